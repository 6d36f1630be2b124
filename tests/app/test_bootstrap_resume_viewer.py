"""The viewer resumes a stopped bootstrap as `inceptiongs bootstrap RUN --out RUN2 --resume` does:
the open result folder, stopped before its end with a checkpoint, is offered "resume", which
continues the bootstrap into the same folder; what is not continued is refused in one line."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import pytest
from train_cases import tiny_demo_run
from viewer_cases import click_widget, opened, wait_for_job_end

STEPS = 8       # refinement steps of the whole bootstrap
STOP_AFTER = 3  # steps made before it is stopped


def _config():
    from inceptiongs.bootstrap.config import BootstrapConfig

    # The default supervision (no prior), small; no checkpoint but the one the stop saves.
    return BootstrapConfig(seed=2, iterations=STEPS, k=2, l=2, log_every=1, save_views=0, checkpoint_every=1000,
                           regenerate_every=0, follow_outlook=False)


@pytest.fixture(scope="module")
def stopped(tmp_path_factory) -> tuple[Path, Path, int]:
    """(stage-I run, the bootstrap of it stopped after STOP_AFTER steps, the iteration it started at)."""
    from inceptiongs.bootstrap.runner import resolve_targets, run_bootstrap
    from inceptiongs.bootstrap.stage1 import load_stage1
    from inceptiongs.live import JobControl

    run = tiny_demo_run(tmp_path_factory.mktemp("boot_resume"), iterations=10,
                        densification={"densify_from": 1000}, pgsr_terms={"normal_from": 1000},
                        output={"log_every": 5, "eval_every": 10, "checkpoint_every": 10})
    stage1 = load_stage1(run)
    targets = resolve_targets(stage1.scene, stage1.split, None, None, 1)
    control = JobControl()

    def stop_at(iteration, gaussians, record) -> None:
        if iteration >= 10 + STOP_AFTER:
            control.stop.set()

    out = run.with_name("run_bootstrap")
    result = run_bootstrap(stage1, out, targets, _config(), control=control, progress=False, on_snapshot=stop_at,
                           snapshot_every=1)
    assert not result.finished and result.iteration == result.start_iteration + STOP_AFTER
    return run, out, result.start_iteration


def _copy(stopped, tmp_path: Path, name: str = "run_bootstrap") -> Path:
    out = tmp_path / name
    shutil.copytree(stopped[1], out)
    return out


def _edit_summary(out: Path, **changes) -> None:
    path = out / "bootstrap" / "summary.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), **changes}))


@dataclasses.dataclass
class _Status:
    text: str = ""


def test_a_stopped_bootstrap_is_offered_resume_and_the_rest_is_refused_in_one_line(stopped, tmp_path):
    from inceptiongs.app.job_requests import bootstrap_resume_request
    from inceptiongs.app.runs import can_resume, resume_blocked_reason

    from inceptiongs.bootstrap.config import BootstrapConfig
    from inceptiongs.runs.lock import run_folder_lock

    run = stopped[0]
    out = _copy(stopped, tmp_path)
    assert can_resume(out) and resume_blocked_reason(out) is None
    status = _Status()
    request = bootstrap_resume_request(out, status)
    assert request is not None, status.text
    job = request.job
    assert request.kind == "bootstrap resume" and request.out_dir == out
    assert job.resume and job.out_dir == out and job.run_dir == run.resolve()
    assert job.config == BootstrapConfig.load(out / "bootstrap" / "config.json")  # the settings it started with
    assert str(out) in request.question and f"iteration {stopped[2] + STOP_AFTER}" in request.question

    def refused(folder: Path, words: str) -> None:
        status = _Status()
        assert bootstrap_resume_request(folder, status) is None
        assert words in status.text and "\n" not in status.text, status.text
        assert status.text.startswith(f"bootstrap resume could not start: {folder}: ")
        # Offered, then refused on the click, only where the stage-I run's own config says blocks.
        assert not can_resume(folder) or folder == out

    finished = _copy(stopped, tmp_path, "finished")
    _edit_summary(finished, stopped=False)
    refused(finished, "this bootstrap finished: nothing is left to resume")
    assert "finished" in resume_blocked_reason(finished)
    baseline = _copy(stopped, tmp_path, "baseline")
    _edit_summary(baseline, baseline=True)
    (baseline / "bootstrap" / "targets.json").unlink()
    refused(baseline, "same-time baseline")
    blocks = _copy(stopped, tmp_path, "blocks")
    _edit_summary(blocks, blocks_refined=[0])
    refused(blocks, "a bootstrap of a run in blocks is not resumed")
    unsaved = _copy(stopped, tmp_path, "unsaved")
    shutil.rmtree(unsaved / "checkpoints")
    refused(unsaved, "stopped before it saved a checkpoint")
    with run_folder_lock(out):          # another job writes it
        refused(out, "in use by pid")
    # The stage-I run in blocks (its config says so): refused as the command refuses --resume there.
    in_blocks = tmp_path / "stage1_in_blocks"
    shutil.copytree(run, in_blocks)
    config = json.loads((in_blocks / "config.json").read_text())
    (in_blocks / "config.json").write_text(json.dumps({**config, "blocks": 2}))
    _edit_summary(out, run=str(in_blocks))
    refused(out, "a bootstrap of a run in blocks is not resumed")


@pytest.mark.gl
@pytest.mark.slow
def test_the_panel_resumes_a_stopped_bootstrap_to_its_end(xvfb, stopped, tmp_path):
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer

    out = _copy(stopped, tmp_path)
    start, stopped_at = stopped[2], stopped[2] + STOP_AFTER
    with opened(Viewer, open_source(out), 900, 1000) as viewer:
        assert viewer.jobs.run_dir == out
        viewer.step()
        assert "resume" in viewer.ui.rects and "why no resume" not in viewer.ui.rects
        click_widget(viewer, "resume")
        asked = viewer.jobs.pending
        assert asked is not None and asked.kind == "bootstrap resume", viewer.status
        assert viewer.jobs.training is None                      # asked first: nothing runs yet
        shown = viewer.view.model_version
        click_widget(viewer, "start the job")
        job = viewer.jobs.training.job
        assert job.resume and job.out_dir == out
        assert viewer.jobs.training.plan.start_iteration == stopped_at and viewer.jobs.training.plan.resumed
        wait_for_job_end(viewer, 180)
        run = viewer.jobs.training
        assert not run.alive and run.error is None, run.error
        assert "bootstrap finished" in run.progress.message, run.progress.message
        assert run.progress.iteration == start + STEPS
        assert viewer.view.model_version > shown, "the refinement should be shown live"
        summary = json.loads((out / "bootstrap" / "summary.json").read_text())
        assert summary["stopped"] is False and summary["resumed_at"] == stopped_at
        assert summary["iteration"] == start + STEPS
        # Its verdict, as at the end of any bootstrap.
        assert viewer.jobs.verdict is not None and viewer.jobs.verdict.out_dir == out
        assert viewer.jobs.verdict.iterations == (start, start + STEPS)
        assert "bootstrap finished" in viewer.status and str(out) in viewer.status, viewer.status
        viewer.step()
        assert "resume" not in viewer.ui.rects or "why no resume" in viewer.ui.rects   # finished: not offered
