"""The student as a harness agent: ``--agent student --agent-config MODEL_CHECKPOINT``.

Every 0.05 s tick: BEV (binarised as in training, model.cache.binarize), target point (ego
frame, x forward, y left) [m] and speed [m/s] in; the network's path (20, 2) and speed
waypoints (10, 2) out, through SimLingo's controller (controller.simlingo) to a Control.
run_step returns ``(Control, Prediction)`` so the harness logs the waypoints for the
stability metrics and ``render``. The mode head is not used at inference.

Torch runs on one thread per process (eval workers are processes, one per core).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from controller.simlingo import SimLingoController
from controller.vehicle import Control
from harness.agent import AutonomousAgent, Prediction
from model.cache import binarize
from model.checkpoint import load_checkpoint

INFERENCE_THREADS = 1


class StudentAgent(AutonomousAgent):
    def setup(self, config: str | None) -> None:
        super().setup(config)
        if not config:
            raise ValueError("the student agent needs --agent-config MODEL_CHECKPOINT (a student.pt file or "
                             "the --out folder of 'sumo-scimm train')")
        torch.set_num_threads(INFERENCE_THREADS)
        self.model, self.manifest = load_checkpoint(config)
        self.controller = SimLingoController()

    def check_config(self, config: str | None) -> None:
        if not config:
            raise ValueError("the student agent needs --agent-config MODEL_CHECKPOINT")
        load_checkpoint(config)  # BadInput with one line if missing, corrupt or unsafe

    def sensors(self) -> list[dict]:
        return [{"type": "bev", "id": "bev"}, {"type": "target_point", "id": "target_point"},
                {"type": "speed", "id": "speed"}]

    @torch.inference_mode()
    def predict(self, bev: np.ndarray, target_point: np.ndarray, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """(path (20, 2), speed waypoints (10, 2)) [m], ego frame, for one frame's inputs."""
        x = torch.from_numpy(binarize(bev)[None].astype(np.float32))  # (1, 9, 64, 64)
        tp = torch.as_tensor(np.asarray(target_point, dtype=np.float32)[None])  # (1, 2)
        sp = torch.tensor([speed], dtype=torch.float32)  # (1,)
        out = self.model(x, tp, sp)
        return out["path"][0].numpy().astype(float), out["speed_wps"][0].numpy().astype(float)

    def run_step(self, input_data: dict, timestamp: float) -> tuple[Control, Prediction]:
        speed = float(input_data["speed"])
        path, speed_wps = self.predict(input_data["bev"], input_data["target_point"], speed)
        return self.controller.step(path, speed_wps, speed), Prediction(path=path, speed_wps=speed_wps)


# The students shipped with the package (``sumo-scimm reproduce`` makes them; each folder
# holds student.pt and the manifest saying how it was made): ``--agent baseline|fixed|scimm``.
SHIPPED = Path(__file__).parent / "checkpoints"


class ShippedStudent(StudentAgent):
    """A student whose checkpoint ships in ``model/checkpoints/<ARM>``; ``--agent-config``
    may still point at another checkpoint."""

    ARM = ""

    def _checkpoint(self, config: str | None) -> str:
        path = SHIPPED / self.ARM / "student.pt"
        if not config and not path.is_file():
            raise FileNotFoundError(f"no shipped checkpoint {path}: train one with 'sumo-scimm reproduce' "
                                    "and copy its models/<arm>_s0 folder there, or pass --agent-config")
        return config or str(path)

    def check_config(self, config: str | None) -> None:
        super().check_config(self._checkpoint(config))

    def setup(self, config: str | None) -> None:
        super().setup(self._checkpoint(config))


class BaselineStudent(ShippedStudent):
    ARM = "baseline"


class FixedStudent(ShippedStudent):
    ARM = "fixed"


class ScimmStudent(ShippedStudent):
    ARM = "scimm"
