"""What a training checkpoint must hold before a resume may use it.

A checkpoint from another version, another program or a crafted file can be valid data and still
be no checkpoint: missing keys, parameters of mismatched lengths, an optimizer state for other
parameters, random states that do not restore. :func:`checkpoint_problem` names the first such
problem in words, so the loader can refuse the file in one line instead of failing deep inside a
resume with a traceback.
"""

from __future__ import annotations

import math

import numpy as np
import torch

PARAM_SHAPES = {"means": (3,), "log_scales": (3,), "quats": (4,), "opacity_logits": (), "sh_dc": (1, 3)}
STATS_KEYS = ("grad_sum", "count", "max_radii")


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def params_problem(params) -> str | None:
    """None when ``params`` is {name: float tensor [N, ...]} with the Gaussians' names and shapes."""
    if not isinstance(params, dict):
        return "params is not a dict"
    missing = sorted(set(PARAM_SHAPES) - set(params))
    if missing:
        return f"params lacks {', '.join(missing)}"
    unknown = sorted(set(params) - set(PARAM_SHAPES) - {"sh_rest"})
    if unknown:
        return f"unknown params {', '.join(map(str, unknown))}"
    if not all(isinstance(t, torch.Tensor) and t.is_floating_point() for t in params.values()):
        return "params are not all floating-point tensors"
    other = sorted({str(t.dtype).removeprefix("torch.") for t in params.values()} - {"float32"})
    if other:   # the model, its optimizer and the losses are float32 throughout
        return f"params are {', '.join(other)}, not float32"
    n = params["means"].shape[0] if params["means"].ndim else -1
    for name, tail in PARAM_SHAPES.items():
        if tuple(params[name].shape) != (n, *tail):
            return f"params {name} has shape {tuple(params[name].shape)}, expected {(n, *tail)}"
    rest = params.get("sh_rest")
    if rest is not None and (rest.ndim != 3 or rest.shape[0] != n or rest.shape[2] != 3
                             or rest.shape[1] + 1 not in (4, 9, 16)):
        return f"params sh_rest has shape {tuple(rest.shape)}"
    for name, tensor in params.items():
        # A resume from NaN or inf trains nothing and writes a model.ply every reader refuses.
        if not bool(torch.isfinite(tensor).all()):
            return f"params {name} holds {int((~torch.isfinite(tensor)).sum())} non-finite values"
    return None


def _tensors_problem(name: str, value, n: int, required: tuple[str, ...]) -> str | None:
    if not isinstance(value, dict) or not all(isinstance(t, torch.Tensor) for t in value.values()):
        return f"{name} is not a dict of tensors"
    missing = sorted(set(required) - set(value))
    if missing:
        return f"{name} lacks {', '.join(missing)}"
    if any(t.ndim == 0 or t.shape[0] != n for t in value.values()):
        return f"{name} does not have one row per Gaussian ({n})"
    return None


def _optimizer_problem(optimizer, count: int) -> str | None:
    if not isinstance(optimizer, dict) or not isinstance(optimizer.get("state"), dict) \
            or not isinstance(optimizer.get("param_groups"), list):
        return "optimizer is not an optimizer state"
    groups = optimizer["param_groups"]
    if not all(isinstance(g, dict) and isinstance(g.get("params"), list) for g in groups):
        return "optimizer param_groups are malformed"
    if sum(len(g["params"]) for g in groups) != count:
        return f"optimizer holds state for {sum(len(g['params']) for g in groups)} parameters, not {count}"
    return None


def _random_states_problem(payload: dict) -> str | None:
    try:
        np.random.default_rng().bit_generator.state = payload["view_rng"]
        torch.Generator().set_state(payload["generator"])
    except Exception as exc:  # noqa: BLE001 - any failure means the state cannot be restored
        return f"random state does not restore ({type(exc).__name__})"
    return None


def checkpoint_problem(payload) -> str | None:
    """None when ``payload`` holds everything a resume reads, else what is wrong, in words."""
    if not isinstance(payload, dict):
        return "not a dict"
    required = ("iteration", "wall_s", "train_s", "params", "optimizer", "stats", "view_rng", "generator",
                "order", "order_pos", "logged")
    missing = [key for key in required if key not in payload]
    if missing:
        return f"missing {', '.join(missing)}"
    if not _is_int(payload["iteration"]) or payload["iteration"] < 0:
        return "iteration is not a count"
    if not (_is_number(payload["wall_s"]) and _is_number(payload["train_s"])):
        return "wall_s/train_s are not finite numbers"
    problem = params_problem(payload["params"])
    if problem is not None:
        return problem
    n = payload["params"]["means"].shape[0]
    problem = (_optimizer_problem(payload["optimizer"], len(payload["params"]))
               or _tensors_problem("stats", payload["stats"], n, STATS_KEYS)
               or ("view_stats" in payload and _tensors_problem("view_stats", payload["view_stats"], n, ()))
               or _random_states_problem(payload))
    if problem:
        return problem
    if not (isinstance(payload["order"], list) and all(_is_int(v) for v in payload["order"])
            and _is_int(payload["order_pos"]) and 0 <= payload["order_pos"] <= len(payload["order"])):
        return "view order is malformed"
    if not (isinstance(payload["logged"], list) and all(isinstance(v, str) for v in payload["logged"])):
        return "logged is not a list of strings"
    if not isinstance(payload.get("view_mse", {}), dict):
        return "view_mse is not a dict"
    return None
