"""Published experiments the simulator is checked against: ``cases`` (the case table and ``evaluate``),
``errors`` (the error figures) and ``data/`` (the experiments' series with their citations)."""
