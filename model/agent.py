"""The student as a harness agent: ``--agent student --agent-config MODEL_CHECKPOINT``.

Every 0.05 s tick: BEV (binarised as in training, model.cache.binarize), target point (ego
frame, x forward, y left) [m] and speed [m/s] in (the speed reaches the network only if
its checkpoint has NetConfig.speed_input on; the controller always); the network's path
(20, 2) and speed waypoints (10, 2) out, through SimLingo's controller
(controller.simlingo) to a Control.
run_step returns ``(Control, Prediction)`` so the harness logs the waypoints for the
stability metrics and ``render``. The mode head is not used at inference.

The network runs in ONNX Runtime on one thread per process (model.runtime: exported from
the checkpoint's torch module when the agent is set up; eval workers are processes, one
per core): about 0.3 instead of 0.8 ms a frame in torch, outputs equal to the torch
module's to rounding (a few 1e-6 m).

A tick whose network inputs (binarised BEV, target point and, for a network with the speed
input, speed, as float32) equal the previous tick's value for value gets the previous tick's
outputs without running the network again: a standing ego in a still scene. The network
is a pure function of its inputs (same inputs, same outputs:
tests/test_student_controller.py), so records do not change.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import torch

from controller.simlingo import SimLingoController
from controller.vehicle import Control
from harness.loop.agent import AutonomousAgent, Prediction
from model.cache import binarize
from model.checkpoint import load_checkpoint, resolve
from model.runtime import INFERENCE_THREADS, OnnxNetwork


@functools.lru_cache(maxsize=8)
def _loaded(key: tuple[str, int, int]) -> tuple[torch.nn.Module, dict, OnnxNetwork]:
    """The checkpoint at key[0] (key: path, mtime [ns], size), loaded and exported once per
    process: an eval worker sets up a new agent for every route, and every export (a trace
    underneath) keeps memory that is never freed (0.16-0.45 MB per export, measured with and
    without handing freed memory back; a TorchScript trace kept about 5 MB). Eight places:
    a replay sets up each of its students on every route, and more students than places
    would export every one of them again on every route."""
    model, manifest = load_checkpoint(key[0])
    return model, manifest, OnnxNetwork(model)


class StudentAgent(AutonomousAgent):
    def setup(self, config: str | None) -> None:
        super().setup(config)
        if not config:
            raise ValueError("the student agent needs --agent-config MODEL_CHECKPOINT (a student.pt file or "
                             "the --out folder of 'sumo-scimm train')")
        torch.set_num_threads(INFERENCE_THREADS)
        path = resolve(config)
        if not path.is_file():
            load_checkpoint(path)  # raises the one-line BadInput naming the missing file
        st = path.stat()
        self.model, self.manifest, self.network = _loaded((str(path.resolve()), st.st_mtime_ns, st.st_size))
        self.controller = SimLingoController()
        self._forget()

    def use(self, model: torch.nn.Module) -> None:
        """Drive with ``model`` (put in eval mode and exported to ONNX Runtime)."""
        self.model = model.eval()
        self.network = OnnxNetwork(self.model)
        self._forget()

    def _forget(self) -> None:
        self._last = None  # (inputs as compared, path, speed waypoints) of the last network call
        self.frames = self.network_calls = 0  # predict calls, and those that ran the network

    def check_config(self, config: str | None) -> None:
        if not config:
            raise ValueError("the student agent needs --agent-config MODEL_CHECKPOINT")
        load_checkpoint(config)  # BadInput with one line if missing, corrupt or unsafe

    def sensors(self) -> list[dict]:
        return [{"type": "bev", "id": "bev"}, {"type": "target_point", "id": "target_point"},
                {"type": "speed", "id": "speed"}]

    def predict(self, bev: np.ndarray, target_point: np.ndarray, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """(path (20, 2), speed waypoints (10, 2)) [m], ego frame, for one tick's inputs: bev
        (9, 64, 64) uint8, target point (2,) [m] ego frame, speed [m/s]. Inputs equal to the
        previous call's, as the network sees them, give the previous outputs (module doc)."""
        x = binarize(bev)  # (9, 64, 64) bool
        tp = np.array(target_point, dtype=np.float32)
        sp = np.float32(speed)
        self.frames += 1
        # what the network sees, compared as NumPy's == would: the BEV's bytes (each 0 or 1),
        # the float32 target point and speed as Python floats (about 5 us a tick less than
        # np.array_equal on the arrays)
        seen = (x.tobytes(), tp.tolist(), float(sp) if self.network.takes_speed else None)
        last = self._last
        if last is None or seen != last[0]:
            self.network_calls += 1
            last = self._last = (seen, *self.infer(x, tp, sp))
        return last[1].copy(), last[2].copy()

    def infer(self, x: np.ndarray, target_point: np.ndarray, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """One network call: x the binarised BEV (9, 64, 64) (bool or {0, 1}), target point (2,)
        [m] and speed [m/s] -> (path (20, 2), speed waypoints (10, 2)) [m], ego frame."""
        return self.network(x, target_point, speed)

    def run_step(self, input_data: dict, timestamp: float) -> tuple[Control, Prediction]:
        speed = float(input_data["speed"])
        path, speed_wps = self.predict(input_data["bev"], input_data["target_point"], speed)
        return self.controller.step(path, speed_wps, speed), Prediction(path=path, speed_wps=speed_wps)


# The students shipped with the package (``sumo-scimm reproduce`` makes them; each folder
# holds student.pt and the manifest saying how it was made):
# ``--agent baseline|control|fixed|scimm|smoother``.
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


class ControlStudent(ShippedStudent):
    ARM = "control"


class FixedStudent(ShippedStudent):
    ARM = "fixed"


class ScimmStudent(ShippedStudent):
    ARM = "scimm"


class SmootherStudent(ShippedStudent):
    ARM = "smoother"
