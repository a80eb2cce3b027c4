"""Simulated measurements from the forward model (arms, joint errors, streamed rows): the basis of tests and
benchmarks."""
