"""Files written whole or not at all (``atomic``), for every stage: no stage of the data
flow is imported here, so the town builders, the route-set builders, the harness and the
training all write through the same code."""
