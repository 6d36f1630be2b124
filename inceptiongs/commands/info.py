"""``inceptiongs info PATH [--json]``: summarise a scene folder or a model file (.ply, .splat, .spz)."""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

from ..errors import InputError

INFO_COVERAGE_POINTS = 1000

HELP = "summarise a scene (format, cameras, resolutions, points, extent, warnings) or a model file"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="scene folder (COLMAP, transforms.json, LLFF) or a model file "
                                     "(.ply, .compressed.ply, .splat, .spz)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument("--strict", action="store_true",
                        help="fail (exit 2) on missing, unreadable or mis-sized images instead of listing them")


def scene_summary(path: Path, strict: bool = False) -> dict:
    """Summary of a scene in its original units. Image problems are warnings unless strict."""
    from ..scene.loader import load_scene

    scene = load_scene(path, require_images=strict)
    norm = scene.normalization
    centers = norm.to_original(np.array([c.center for c in scene.cameras]))
    summary = {
        "path": str(path),
        "kind": "scene",
        "format": scene.format,
        "cameras": len(scene.cameras),
        "resolutions": {f"{w}x{h}": n for (w, h), n in
                        sorted(Counter((c.width, c.height) for c in scene.cameras).items())},
        "camera_models": dict(sorted(Counter(scene.camera_models).items())),
        "sparse_points": int(len(scene.points)),
        "camera_center": centers.mean(axis=0).tolist(),
        # Largest distance of a camera from the cameras' centroid, original units.
        "camera_extent": float(1.0 / norm.scale),
        "warnings": scene.warnings,
    }
    if len(scene.points):
        points = norm.to_original(scene.points)
        summary["points_bounds"] = [points.min(axis=0).tolist(), points.max(axis=0).tolist()]
    summary["coverage"] = coverage_section(scene)
    return summary


def coverage_section(scene) -> dict:
    """Viewing coverage of the sparse points (`inceptiongs coverage` draws it); scenes without
    sparse points say so instead of triangulating here (that takes minutes)."""
    from ..evaluation import coverage_map

    if not len(scene.points):
        return {"available": False, "reason": "no sparse points (inceptiongs coverage triangulates them)"}
    # 1,000 points keep `info` quick on big captures (the cost is points x views^2).
    figures = coverage_map.summary(coverage_map.scene_coverage(scene, max_points=INFO_COVERAGE_POINTS,
                                                               triangulate=False), listed=5)
    return {"available": True, **figures}


def ply_summary(path: Path) -> dict:
    """Summary of a model file of any format (:mod:`inceptiongs.io.models`)."""
    from ..io.models import open_model

    model = open_model(path)
    g = model.gaussians
    summary = {"path": str(path), "kind": "gaussians", "file_format": model.format, "gaussians": len(g),
               "sh_degree": g.sh_degree}
    if len(g):
        means = g.means.numpy()
        summary["bounds"] = [means.min(axis=0).tolist(), means.max(axis=0).tolist()]
    return summary


def _format_vector(values) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in values) + ")"


def format_summary(summary: dict) -> str:
    lines = [f"{summary['path']}"]
    if summary["kind"] == "gaussians":
        lines.append(f"  {summary['file_format']} model: {summary['gaussians']} Gaussians, "
                     f"SH degree {summary['sh_degree']}")
        if "bounds" in summary:
            lines.append(f"  bounds: {_format_vector(summary['bounds'][0])} .. {_format_vector(summary['bounds'][1])}")
        return "\n".join(lines)
    lines.append(f"  format:        {summary['format']}")
    lines.append(f"  cameras:       {summary['cameras']}")
    lines.append("  resolutions:   " + ", ".join(f"{r} ({n})" for r, n in summary["resolutions"].items()))
    lines.append("  camera models: " + ", ".join(f"{m} ({n})" for m, n in summary["camera_models"].items()))
    lines.append(f"  sparse points: {summary['sparse_points']}")
    lines.append(f"  camera extent: {summary['camera_extent']:.4g} (max camera distance from "
                 f"{_format_vector(summary['camera_center'])}, original units)")
    if "points_bounds" in summary:
        lines.append(f"  point bounds:  {_format_vector(summary['points_bounds'][0])} .. "
                     f"{_format_vector(summary['points_bounds'][1])}")
    coverage = summary.get("coverage", {})
    if coverage.get("available"):
        lines.append(f"  coverage:      median {coverage['views_per_point']['median']:g} views per sparse point, "
                     f"{coverage['thinly_seen_fraction']:.0%} seen by fewer than {coverage['thin_threshold_views']}; "
                     "scarcest views " + ", ".join(v["name"] for v in coverage["scarcest_views"]))
    lines.append(f"  warnings:      {len(summary['warnings'])}")
    lines.extend(f"    - {w}" for w in summary["warnings"])
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    path = Path(args.path)
    if not path.exists():
        raise InputError(f"{path}: path does not exist")
    from ..io.models import is_model_file

    summary = ply_summary(path) if path.is_file() and is_model_file(path) else scene_summary(path, args.strict)
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0
