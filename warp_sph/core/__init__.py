"""Core: errors, the launch helper, the step graph, smoothing kernels, Model and State."""
