"""A user's agent module with one import: drives straight ahead at a walking pace."""
from harness.loop.agent import AutonomousAgent, Control


class Walker(AutonomousAgent):
    def sensors(self):
        return [{"type": "speed", "id": "speed"}]

    def run_step(self, input_data, timestamp):
        return Control(throttle=0.3 if input_data["speed"] < 2.0 else 0.0)
