"""Whether a bootstrap helped, as the Training panel shows it once one has ended (or a bootstrap
result is opened): the library's verdict (``inceptiongs.evaluation.verdict``: stage I, the
result and its same-time baseline by group, never a baseline of another length; without one the
sentence says so, and the panel offers to run it) and each flagged view rendered from the
stage-I model and from the result, side by side.

Reading is the library's (read_verdict); the images are rendered with the viewer's renderer
(render_verdict_images, once a frame when due) and drawn here with imgui."""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from inceptiongs.evaluation.verdict import BootstrapVerdict, read_bootstrap_verdict, score_rows, seconds_text
from inceptiongs.evaluation.verdict import verdict_line  # noqa: F401 (the panel's and the status line's sentence)

# Width of each before / after image in the panel, pixels.
THUMBNAIL_WIDTH = 150
RUN_BASELINE = "run the same-time baseline"


@dataclass
class FlagImages:
    """One flagged view rendered from the stage-I model (before) and the result (after):
    [h, w, 3] float in [0, 1]; textures: the GL textures the panel draws them from."""

    name: str
    before: np.ndarray
    after: np.ndarray
    textures: tuple = ()


@dataclass
class Verdict(BootstrapVerdict):
    """The library's verdict of the result in ``out_dir`` and the flagged views' images once
    rendered."""

    images: list = field(default_factory=list)


def read_verdict(run_dir: Path | None) -> Verdict | None:
    """The verdict of the bootstrap result in ``run_dir``; None for anything else (a stage-I
    run, a baseline, a bootstrap without both evaluations yet)."""
    found = read_bootstrap_verdict(run_dir)
    return None if found is None else Verdict(**vars(found))


def draw_verdict(ui, verdict: Verdict | None, offer_baseline: bool = True) -> bool:
    """The panel's "repair verdict" block: the sentence, the scores table, the flagged views
    before / after; without a same-time baseline (and with ``offer_baseline``: no job running),
    a button that offers to run it. The table's rectangle is kept under "verdict", the button's
    under RUN_BASELINE (panels._remember's form). -> whether the button was pressed."""
    if verdict is None:
        return False
    from imgui_bundle import imgui  # noqa: PLC0415 (pure readers above stay importable without imgui)

    imgui.separator_text("repair verdict")
    imgui.push_text_wrap_pos(0.0)
    imgui.text(verdict_line(verdict))
    if verdict.outlook:
        imgui.text_disabled(f"before it started: {verdict.outlook}")
    imgui.pop_text_wrap_pos()
    pressed = False
    if offer_baseline and baseline_offered(verdict):
        pressed = imgui.button(f"{RUN_BASELINE} ({seconds_text(verdict.seconds)})")
        low, high = imgui.get_item_rect_min(), imgui.get_item_rect_max()
        ui.rects[RUN_BASELINE] = (low.x, low.y, high.x, high.y)
        if imgui.is_item_hovered():
            imgui.set_tooltip(f"stage I ({verdict.stage1_run}) continued on the photos alone for the bootstrap's "
                              f"{seconds_text(verdict.seconds)}, into a new folder beside it: the comparison "
                              "that says whether the virtual views helped")
    top = imgui.get_cursor_screen_pos().y
    _score_table(verdict)
    for shown in verdict.images:
        _flag_images(shown)
    right = imgui.get_content_region_avail().x + imgui.get_cursor_screen_pos().x
    ui.rects["verdict"] = (imgui.get_cursor_screen_pos().x, top, right, imgui.get_cursor_screen_pos().y)
    return pressed


def baseline_offered(verdict: Verdict) -> bool:
    """The verdict has no same-time baseline and one can be run: its stage-I run is there and
    the bootstrap's time is known."""
    return (verdict.baseline is None and verdict.seconds is not None and verdict.seconds > 0
            and verdict.stage1_run is not None and (Path(verdict.stage1_run) / "config.json").is_file())


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
                            f"the same time ({seconds_text(verdict.seconds)})")
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


def render_verdict_images(jobs, view, renderer, ctx) -> bool:
    """The ended bootstrap's flagged views of ``jobs`` (jobs.Jobs: its verdict, what a live
    bootstrap started from) rendered from the model it started from and from the result ``view``
    (view.View) shows, as the verdict's images (their textures uploaded to ``ctx``). -> whether
    ``renderer`` drew them: its model is then theirs, not the window's."""
    jobs.verdict_images_due = False
    verdict = jobs.verdict
    if verdict is None:
        return False
    # A live bootstrap started from the model shown then; an opened result from its run's.
    before = jobs.bootstrap_base if jobs.bootstrap_base is not None else stage1_model(verdict.stage1_run)
    views = target_views(verdict.out_dir) or jobs.bootstrap_views
    if before is None or not views:
        return False
    images = render_flag_images(renderer, before, view.edit.visible_arrays(), views, view.settings)
    upload_textures(ctx, images)
    verdict.images = images
    return True


def upload_textures(ctx, images: list[FlagImages]) -> None:
    """A GL texture (moderngl) for each image, so imgui can draw it; retire_textures and release_retired free them."""
    for shown in images:
        shown.textures = tuple(_texture(ctx, image) for image in (shown.before, shown.after))


def _texture(ctx, image: np.ndarray):
    height, width = image.shape[:2]
    rgba = np.empty((height, width, 4), np.uint8)
    rgba[..., :3] = np.clip(image * 255.0 + 0.5, 0, 255).astype(np.uint8)
    rgba[..., 3] = 255
    return ctx.texture((width, height), 4, rgba.tobytes())  # row 0 first: imgui's uv (0, 0) is the top


def retire_textures(verdict: Verdict | None, retired: list) -> None:
    """Move ``verdict``'s GL textures to ``retired``, for release_retired once the frame that may
    have drawn them is rendered: a job started by a click is started inside the panel's frame,
    whose draw data still names the images, and imgui's backend binding a released texture
    (GLError 1282) ended the viewer."""
    for shown in [] if verdict is None else verdict.images:
        retired.extend(shown.textures)
        shown.textures = ()


def release_retired(retired: list) -> None:
    """Release the textures retire_textures set aside (after the frame is rendered, or at close)."""
    for texture in retired:
        texture.release()
    retired.clear()


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
