"""Pieces of bench/fleet_bench.py: timed commands, the sshd fan-out targets, the Ansible side,
the sim-fleet scenarios and the report."""
