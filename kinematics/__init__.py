"""The robot model every package shares: the standard DH chain with base and tracked point (``dh``), joint values
beyond the DH table (``joint_errors``: coupled readings, gear ratio, eccentricity, compliance) and seeded true robots
for simulation (``truth``). numpy and scipy only; imports nothing of the project."""
