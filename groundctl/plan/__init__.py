"""Offline planner: assignment, SCP on OSQP, splines, continuous-time verification."""
