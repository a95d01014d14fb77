"""Running a scene: the Simulation, the runner (frames, exports, checkpoints), watchdog, pre-flight."""
