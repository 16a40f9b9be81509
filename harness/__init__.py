"""The closed loop and the command line (SPEC §3, §9). The CLI lives in ``harness.cli``."""
