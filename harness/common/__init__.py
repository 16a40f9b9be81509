"""Shared helpers of every stage: files written whole or not at all (``atomic``) and the
one exception for bad user input (``errors``). No simulator, no heavy imports."""
