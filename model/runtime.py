"""The student network for closed-loop inference: exported to ONNX and run by ONNX Runtime.

Training runs in torch (model.train); driving runs the same network, exported in memory at
batch 1 with torch's ONNX exporter and executed by ONNX Runtime on one thread. Why: the
network is small (about 6 M multiply-adds a frame), so in torch its cost is the dispatch of
about 100 ATen calls, not their arithmetic: 0.76-0.88 ms a frame in a TorchScript trace on
a 2-core Intel Xeon against 0.26 ms in ONNX Runtime, which fuses the graph and
runs it without per-operator Python or dispatcher overhead (docs/student.md, the
inference paragraph).

The exported graph computes the eager module's function in float32 with other kernels, so
its outputs differ from the eager module's by rounding only: a few 1e-6 m (up to 4.8e-6 m
seen on outputs of up to 18 m; tests/test_model.py checks 2e-5 m). Closed-loop records therefore
depend on the runtime as they depend on the CPU model (docs/reliability.md,
"Determinism"); on one machine ONNX Runtime on one thread is deterministic.
"""
from __future__ import annotations

import io
import warnings

import numpy as np
import onnxruntime as ort
import torch

INFERENCE_THREADS = 1  # one per process: eval workers are processes, one per core
OPSET = 17  # LayerNormalization is an ONNX operator from opset 17 on, so it stays one fused node


class _Outputs(torch.nn.Module):
    """The student with a tuple output (path, speed waypoints), as the exporter needs."""

    def __init__(self, model: torch.nn.Module):
        super().__init__()
        self.model = model

    def forward(self, bev: torch.Tensor, target_point: torch.Tensor, speed: torch.Tensor):
        out = self.model(bev, target_point, speed)
        return out["path"], out["speed_wps"]


def export_onnx(model: torch.nn.Module) -> bytes:
    """``model`` (put in eval mode) as an ONNX graph at batch 1: inputs bev (1, 9, 64, 64)
    float32 in {0, 1}, target_point (1, 2) [m], speed (1,) [m/s]; outputs path (1, 20, 2)
    and speed_wps (1, 10, 2) [m], ego frame. The network has no data-dependent control flow,
    so the trace behind the export is exact. torch 2.13 marks this (TorchScript-based)
    exporter deprecated, but it needs only the ``onnx`` package (the newer torch.export-based
    one also needs onnxscript), and torch is pinned."""
    example = (torch.zeros(1, 9, 64, 64), torch.zeros(1, 2), torch.zeros(1))
    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(_Outputs(model.eval()), example, buf, dynamo=False, opset_version=OPSET,
                          input_names=["bev", "target_point", "speed"], output_names=["path", "speed_wps"])
    return buf.getvalue()


class OnnxNetwork:
    """The exported student in an ONNX Runtime session on one thread (eval workers are
    processes, one per core), all graph optimisations on, sequential execution."""

    def __init__(self, model: torch.nn.Module):
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = INFERENCE_THREADS
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.log_severity_level = 3  # errors only
        self.session = ort.InferenceSession(export_onnx(model), opts, providers=["CPUExecutionProvider"])
        # a student without speed input (NetConfig.speed_input False) exports a graph without it
        self.takes_speed = "speed" in {i.name for i in self.session.get_inputs()}

    def __call__(self, bev: np.ndarray, target_point: np.ndarray, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """bev (9, 64, 64) bool or {0, 1}; target point (2,) [m]; speed [m/s] -> (path (20, 2),
        speed waypoints (10, 2)) [m] as float64, ego frame."""
        feed = {"bev": bev[None].astype(np.float32),
                "target_point": np.asarray(target_point, dtype=np.float32)[None]}
        if self.takes_speed:
            feed["speed"] = np.array([speed], dtype=np.float32)
        path, speed_wps = self.session.run(None, feed)
        return path[0].astype(float), speed_wps[0].astype(float)
