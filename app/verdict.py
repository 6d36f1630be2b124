"""Whether a bootstrap helped, as the Training panel shows it once one has ended (or a bootstrap
result is opened): the held-out scores of stage I (the bootstrap's first evaluation) and of the
result by group (scarce, covered, all), the same-time baseline's where one was run beside it
(stage I continued on the photos alone for the bootstrap's time: RUN2/bootstrap/summary.json
with "baseline": true and the same stage-I run), and each flagged view rendered from the
stage-I model and from the result, side by side.

Reading is pure (read_verdict); the images are rendered by the viewer (Viewer.render_verdict)
and drawn here with imgui."""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from inceptiongs.bootstrap.summary_file import SUMMARY_FILE, read_summary, virtual_step_count

SUMMARY = Path(SUMMARY_FILE)
GROUPS = ("scarce", "covered", "all")
# Width of each before / after image in the panel, pixels.
THUMBNAIL_WIDTH = 150
# A difference within this many dB is reported as no change (held-out PSNR noise).
SAME_DB = 0.05


@dataclass
class FlagImages:
    """One flagged view rendered from the stage-I model (before) and the result (after):
    [h, w, 3] float in [0, 1]; textures: the GL textures the panel draws them from."""

    name: str
    before: np.ndarray
    after: np.ndarray
    textures: tuple = ()


@dataclass
class Verdict:
    """What the panel says about the bootstrap result in ``out_dir``: flat held-out scores
    ("scarce_psnr", ...) of stage I (before) and of the result (after); the same-time baseline's
    (None: none found) and its folder; the flagged views' images once rendered."""

    out_dir: Path
    stage1_run: Path | None
    before: dict
    after: dict
    baseline: dict | None = None
    baseline_dir: Path | None = None
    images: list = field(default_factory=list)
    # What stage I's curve said before the bootstrap started (inceptiongs.bootstrap.outlook).
    outlook: str | None = None
    # Steps that carried a virtual loss (None: unknown); 0 when the loop followed the outlook or
    # every view was left out: the result is then stage I trained longer.
    virtual_steps: int | None = None


def _summary(run_dir: Path) -> dict | None:
    """RUN/bootstrap/summary.json as a dict; None when absent or unreadable (a run being written)."""
    return read_summary(run_dir)


def _scores(data: dict, key: str) -> dict:
    value = data.get(key)
    return {k: v for k, v in value.items() if isinstance(v, (int, float))} if isinstance(value, dict) else {}


def find_baseline(out_dir: Path, stage1_run: Path | None) -> tuple[Path, dict] | None:
    """The newest same-time baseline of ``stage1_run`` beside ``out_dir`` or beside the stage-I
    run (as `inceptiongs demo` lays them out: run, run_bootstrap, run_baseline) -> (its folder,
    its last held-out scores); None when there is none."""
    if stage1_run is None:
        return None
    wanted = Path(stage1_run).resolve()
    found = []
    for parent in {Path(out_dir).resolve().parent, wanted.parent}:
        for folder in (p for p in parent.iterdir() if p.is_dir()) if parent.is_dir() else ():
            data = _summary(folder)
            if (data is None or data.get("baseline") is not True or not _scores(data, "last_eval")
                    or Path(str(data.get("run", ""))).resolve() != wanted):
                continue
            found.append(((folder / SUMMARY).stat().st_mtime, folder, _scores(data, "last_eval")))
    if not found:
        return None
    _, folder, scores = max(found, key=lambda item: item[0])
    return folder, scores


def read_verdict(run_dir: Path | None) -> Verdict | None:
    """The verdict of the bootstrap result in ``run_dir``; None for anything else (a stage-I
    run, a baseline, a bootstrap without both evaluations yet)."""
    if run_dir is None:
        return None
    data = _summary(run_dir)
    if data is None or data.get("baseline") is True:
        return None
    before, after = _scores(data, "initial_eval"), _scores(data, "last_eval")
    if not before or not after:
        return None
    stage1 = Path(data["run"]) if isinstance(data.get("run"), str) else None
    outlook = data.get("outlook")
    steps = data.get("steps")
    counted = isinstance(steps, dict) and all(isinstance(v, int) for v in steps.values())
    verdict = Verdict(Path(run_dir), stage1, before, after,
                      outlook=outlook.get("line") if isinstance(outlook, dict) and isinstance(outlook.get("line"), str)
                      else None, virtual_steps=virtual_step_count(steps) if counted else None)
    baseline = find_baseline(Path(run_dir), stage1)
    if baseline is not None:
        verdict.baseline_dir, verdict.baseline = baseline
    return verdict


def score_rows(verdict: Verdict) -> list[tuple[str, float, float, float | None]]:
    """[(group, stage I dB, bootstrap dB, baseline dB or None)] for the groups the result scored."""
    rows = []
    for group in GROUPS:
        key = f"{group}_psnr"
        if key in verdict.before and key in verdict.after:
            baseline = None if verdict.baseline is None else verdict.baseline.get(key)
            rows.append((group, verdict.before[key], verdict.after[key], baseline))
    return rows


def _change(difference: float, other: str) -> str:
    """How the result compares with ``other`` ("the same-time baseline", "stage I")."""
    if abs(difference) < SAME_DB:
        return f"about the same as {other} ({difference:+.2f} dB)"
    return f"{'better' if difference > 0 else 'worse'} by {abs(difference):.2f} dB than {other}"


def verdict_line(verdict: Verdict) -> str:
    """One sentence: how the result compares on the scarce views (else the first group scored)
    with the same-time baseline, or with stage I when no baseline was run."""
    rows = score_rows(verdict)
    if not rows:
        return "no held-out scores to judge the bootstrap by"
    group, before, after, baseline = rows[0]
    if baseline is not None:
        return f"{group} views: {_change(after - baseline, 'the same-time baseline')}"
    if verdict.virtual_steps == 0:
        return (f"{group} views: {_change(after - before, 'stage I')}; no virtual step ran (the loop followed "
                "the outlook, or every view was left out), so this is stage I trained longer")
    return (f"{group} views: {_change(after - before, 'stage I')}; no same-time baseline was run, so "
            "part of that may be the extra training alone")


def draw_verdict(ui, verdict: Verdict | None) -> None:
    """The panel's "repair verdict" block: the sentence, the scores table, the flagged views
    before / after. The table's rectangle is kept under "verdict" (panels._remember's form)."""
    if verdict is None:
        return
    from imgui_bundle import imgui  # noqa: PLC0415 (pure readers above stay importable without imgui)

    imgui.separator_text("repair verdict")
    imgui.push_text_wrap_pos(0.0)
    imgui.text(verdict_line(verdict))
    if verdict.outlook:
        imgui.text_disabled(f"before it started: {verdict.outlook}")
    imgui.pop_text_wrap_pos()
    top = imgui.get_cursor_screen_pos().y
    _score_table(verdict)
    for shown in verdict.images:
        _flag_images(shown)
    right = imgui.get_content_region_avail().x + imgui.get_cursor_screen_pos().x
    ui.rects["verdict"] = (imgui.get_cursor_screen_pos().x, top, right, imgui.get_cursor_screen_pos().y)


def _score_table(verdict: Verdict) -> None:
    from imgui_bundle import imgui  # noqa: PLC0415

    rows = score_rows(verdict)
    with_baseline = verdict.baseline is not None
    columns = ["PSNR (dB)", "stage I", "bootstrap"] + (["baseline"] if with_baseline else [])
    if not rows or not imgui.begin_table("verdict scores", len(columns), imgui.TableFlags_.borders_inner_h):
        return
    for name in columns:
        imgui.table_setup_column(name)
    imgui.table_headers_row()
    for group, before, after, baseline in rows:
        imgui.table_next_row()
        cells = [group, f"{before:.2f}", f"{after:.2f}"] + ([f"{baseline:.2f}"] if with_baseline else [])
        for cell in cells:
            imgui.table_next_column()
            imgui.text(cell)
    imgui.end_table()
    if with_baseline:
        imgui.push_text_wrap_pos(0.0)
        imgui.text_disabled(f"baseline: {verdict.baseline_dir.name}, stage I continued on the photos alone for "
                            "the same time")
        imgui.pop_text_wrap_pos()


def _flag_images(shown: FlagImages) -> None:
    from imgui_bundle import imgui  # noqa: PLC0415

    if not shown.textures:
        return
    height, width = shown.before.shape[:2]
    size = imgui.ImVec2(float(width), float(height))
    imgui.text(f"{shown.name}: stage I | bootstrap")
    before, after = shown.textures
    imgui.image(imgui.ImTextureRef(before.glo), size)
    imgui.same_line()
    imgui.image(imgui.ImTextureRef(after.glo), size)


def target_views(out_dir: Path) -> list:
    """[(name, Camera)] the bootstrap in ``out_dir`` repaired (RUN2/bootstrap/targets.json, in the
    scene's normalised frame as the viewer shows it); [] when absent or unreadable."""
    from inceptiongs.bootstrap.targets import targets_from_json  # noqa: PLC0415
    from inceptiongs.errors import InputError  # noqa: PLC0415

    path = Path(out_dir) / "bootstrap" / "targets.json"
    try:
        targets = targets_from_json(json.loads(path.read_text(encoding="utf-8")), str(path))
    except (OSError, UnicodeDecodeError, ValueError, InputError):
        return []
    return [(target.name, target.camera) for target in targets]


def stage1_model(run_dir: Path | None) -> dict | None:
    """The stage-I run's Gaussians (arrays, the normalised frame the viewer shows a run in);
    None when the run cannot be read (moved, deleted)."""
    from inceptiongs.errors import InputError  # noqa: PLC0415
    from inceptiongs.runs.load import load_run  # noqa: PLC0415

    if run_dir is None:
        return None
    try:
        return load_run(Path(run_dir))[0].numpy()
    except (InputError, OSError, ValueError):
        return None


def thumbnail_camera(camera, width: int = THUMBNAIL_WIDTH):
    """``camera`` at ``width`` pixels wide, its aspect and view kept."""
    from .screenshot import resized  # noqa: PLC0415

    height = max(int(round(camera.height * width / camera.width)), 1)
    return resized(camera, width, height)


def render_flag_images(renderer, before: dict, after: dict, views: list, settings) -> list[FlagImages]:
    """Each flagged view (views: [(name, Camera)]) rendered by the GL ``renderer`` from the
    ``before`` and ``after`` Gaussians (arrays as Gaussians.numpy()) at thumbnail size, with the
    view's SH cap and splat scale. Leaves ``after`` uploaded; the caller re-uploads its model."""
    from .images import visualize  # noqa: PLC0415

    def render(camera):
        image = renderer.render(camera, mode="rgb", background=settings.background,
                                sh_degree_cap=settings.sh_degree_cap, splat_scale=settings.splat_scale)
        return visualize(image, "rgb")

    cameras = [(name, thumbnail_camera(camera)) for name, camera in views]
    renderer.set_gaussians(before)
    befores = [render(camera) for _, camera in cameras]
    renderer.set_gaussians(after)
    return [FlagImages(name, image, render(camera)) for (name, camera), image in zip(cameras, befores)]


def upload_textures(ctx, images: list[FlagImages]) -> None:
    """A GL texture (moderngl) for each image, so imgui can draw it; release_textures frees them."""
    for shown in images:
        shown.textures = tuple(_texture(ctx, image) for image in (shown.before, shown.after))


def _texture(ctx, image: np.ndarray):
    height, width = image.shape[:2]
    rgba = np.empty((height, width, 4), np.uint8)
    rgba[..., :3] = np.clip(image * 255.0 + 0.5, 0, 255).astype(np.uint8)
    rgba[..., 3] = 255
    return ctx.texture((width, height), 4, rgba.tobytes())  # row 0 first: imgui's uv (0, 0) is the top


def release_textures(verdict: Verdict | None) -> None:
    for shown in [] if verdict is None else verdict.images:
        for texture in shown.textures:
            texture.release()
        shown.textures = ()


def outlook_before_repair(run_dir: Path | None) -> str | None:
    """What a bootstrap of the open stage-I run would face (inceptiongs.bootstrap.outlook), said
    before the user starts one; None for no run or a bootstrap's result. Re-read only when the
    run's metrics change (the panel asks every frame)."""
    if run_dir is None or (Path(run_dir) / "bootstrap").exists():
        return None
    try:
        stamp = (Path(run_dir) / "metrics.jsonl").stat().st_mtime_ns
    except OSError:
        return None
    return _outlook_line(str(run_dir), stamp)


@functools.lru_cache(maxsize=8)
def _outlook_line(run_dir: str, stamp: int) -> str:
    from inceptiongs.bootstrap.outlook import run_outlook  # noqa: PLC0415

    return run_outlook(run_dir).line
