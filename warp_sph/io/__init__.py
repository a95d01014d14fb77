"""Files: the run folder, USD for Blender, mesh sequences, re-export of recorded runs."""
