"""Parameter sweeps: many ordinary runs, in this process or on Dask (``warp-sph sweep``).

    cases.py      the product of --param lists, or a TOML sweep file -> Case list, folder names
    executors.py  SerialExecutor (in-process) and DaskExecutor (LocalCluster or an existing cluster)
    runs.py       one case: an ordinary run into DIR/<case>, resume, its summary row, peak memory
    summary.py    DIR/sweep.jsonl and the results page DIR/sweep.md with the speed/accuracy plot
    driver.py     run_sweep: plan (skip complete cases), submit, collect, progress, Ctrl-C

The executors run any module-level task function, so ``warp-sph bench`` uses them too. Dask is
optional (the ``distributed`` extra); nothing here imports it unless a Dask executor is made.
"""
from .cases import Case, SweepError, build_cases, is_sweep_file, load_sweep_file, parse_param
from .driver import run_sweep
from .executors import DaskExecutor, MissingExtraError, Outcome, SerialExecutor, make_executor

__all__ = ["Case", "DaskExecutor", "MissingExtraError", "Outcome", "SerialExecutor", "SweepError", "build_cases",
           "is_sweep_file", "load_sweep_file", "make_executor", "parse_param", "run_sweep"]
