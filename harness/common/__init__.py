"""Shared helpers of the harness: the one exception for bad user input (``errors``), the lock that gives a run folder to one
command (``lock``) and the count of the user's stops (``stops``). No simulator, no heavy
imports."""
