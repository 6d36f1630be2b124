"""The viewer's Bootstrap action: stage II on the flagged views as the live job (Xvfb)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from train_cases import tiny_demo_run
from viewer_cases import opened

pytestmark = [pytest.mark.gl, pytest.mark.slow]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    return tiny_demo_run(tmp_path_factory.mktemp("viewer_bootstrap"), iterations=10,
                         densification={"densify_from": 1000}, pgsr_terms={"normal_from": 1000},
                         output={"log_every": 5, "eval_every": 10, "checkpoint_every": 10})


def test_bootstrap_button_runs_the_flagged_views_live(xvfb, run_dir):
    from inceptiongs.app.sources import open_source
    from inceptiongs.app.viewer import Viewer
    from inceptiongs.bootstrap.config import BootstrapConfig

    with opened(Viewer, open_source(run_dir), 320, 240) as viewer:
        viewer.step()
        viewer.jobs.start_bootstrap()
        assert viewer.jobs.training is None and "no flagged views" in viewer.status
        viewer.view.snap_to_camera(0)
        viewer.flags.flag_current_view()          # a 320x240 flag; the job rescales it to 48x36
        # The button's action with a tiny configuration (its default is a full bootstrap).
        viewer.jobs.start_bootstrap(BootstrapConfig(iterations=6, k=1, l=2, ddim_steps=1, prior="untrained",
                                                log_every=1, save_views=0))
        job = viewer.jobs.training.job
        assert job.targets_file == viewer.flags.file and job.run_dir == run_dir
        versions, deadline = set(), time.time() + 120
        while viewer.jobs.training.alive and time.time() < deadline:
            before = viewer.view.model_version
            viewer.step()
            if viewer.view.model_version != before:
                versions.add(viewer.view.model_version)
        assert viewer.jobs.training.error is None, viewer.jobs.training.error
        viewer.step()
        assert len(versions) >= 1, "the job's snapshots should reach the renderer"
        assert "bootstrap finished" in viewer.jobs.training.progress.message
        first = run_dir.with_name("run_bootstrap") / "model.ply"
        assert first.is_file()
        assert viewer.jobs.run_dir == run_dir.with_name("run_bootstrap")  # the result is the open run now
        # Bootstrapping again (here: the original run) writes a new folder; the first result stays.
        first_bytes = first.read_bytes()
        viewer.jobs.run_dir = run_dir
        viewer.jobs.start_bootstrap(BootstrapConfig(iterations=2, k=1, l=2, ddim_steps=1, prior="untrained",
                                                log_every=1, save_views=0))
        assert viewer.jobs.training.job.out_dir == run_dir.with_name("run_bootstrap_2")
        assert "run_bootstrap_2" in viewer.title
        viewer.jobs.training.stop(timeout=120)
        assert first.read_bytes() == first_bytes
        assert (run_dir.with_name("run_bootstrap") / "checkpoints").is_dir()
