"""The run folder's own readers (the metrics log on resume, the view-fit report, a run's config
when a scene lists its runs) go through the read guard: a symlink planted in a shared run is
refused in one line naming the file, never followed out of the run."""

from __future__ import annotations

import json

import pytest

from inceptiongs.errors import InputError
from inceptiongs.runs.folder import is_run_of
from inceptiongs.runs.metrics import logged_iterations, truncate_metrics
from inceptiongs.train.view_fit import VIEW_FIT_FILE, read_poorly_fit


@pytest.fixture
def outside(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text(json.dumps({"iteration": 1}) + "\n")
    return secret


def test_a_planted_metrics_symlink_is_refused_not_followed(tmp_path, outside):
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.jsonl").symlink_to(outside)
    for read in (lambda: truncate_metrics(run, 5), lambda: logged_iterations(run)):
        with pytest.raises(InputError) as caught:
            read()
        message = str(caught.value)
        assert message.startswith(str(run)) and "metrics.jsonl" in message and "refused" in message
        assert "\n" not in message
    assert outside.read_text() == json.dumps({"iteration": 1}) + "\n"     # untouched


def test_a_planted_view_fit_symlink_and_config_symlink_are_not_read(tmp_path, outside):
    run = tmp_path / "run"
    run.mkdir()
    (run / VIEW_FIT_FILE).symlink_to(outside)
    with pytest.raises(InputError, match="view_fit"):
        read_poorly_fit(run)
    (run / "model.ply").write_bytes(b"ply\n")
    (run / "config.json").symlink_to(outside)
    assert is_run_of(run, tmp_path) is False


def test_the_metrics_log_still_reads_and_truncates(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.jsonl").write_text("".join(json.dumps({"iteration": i}) + "\n" for i in (0, 5, 10)) + '{"iter')
    assert logged_iterations(run) == {0, 5, 10}
    truncate_metrics(run, 5)
    assert logged_iterations(run) == {0, 5}
