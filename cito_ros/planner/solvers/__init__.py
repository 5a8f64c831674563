"""The solvers behind one interface (`base.Solver`): iLQR, mujoco.minimize's Levenberg-Marquardt and
IPOPT, each driven by the same `base.IterationMonitor`."""
