"""Methods: pressure solvers and boundary methods (one host module each, kernels of the same name)."""
