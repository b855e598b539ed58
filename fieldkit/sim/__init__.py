"""Simulation: many robots, each with its own Buzz VM, over an imperfect radio network.

`radio` holds the delivery model (range, seeded random drop, delay); `harness` steps N VMs
over it in lock step. Everything is seeded: a run is reproducible bit for bit.
"""
