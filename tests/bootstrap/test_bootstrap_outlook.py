"""The repair outlook read from a stage-I run's held-out curve before a bootstrap starts: nothing
to repair where the scarce views render as well as the covered ones, train longer while photo
steps still lift the scarce views, worth a repair otherwise; and where it is shown (the bootstrap's
log and summary, `inceptiongs eval`)."""

from __future__ import annotations

import json
import math

import pytest

from inceptiongs.bootstrap.outlook import (NOTHING_TO_REPAIR_DB, STILL_RISING_DB_PER_MIN, gain_decay_minutes,
                                           gain_per_minute, outlook_from_curve, photo_first_minutes,
                                           recorded_outlook, run_outlook)


def _curve(scarce: list[float], covered: list[float], minutes_apart: float = 1.0) -> list[dict]:
    lines = []
    for index, (s, c) in enumerate(zip(scarce, covered)):
        lines.append({"iteration": 100 * index, "train_s": 60.0 * minutes_apart * index, "loss": 0.1})
        lines.append({"iteration": 100 * index, "train_s": 60.0 * minutes_apart * index,
                      "scarce_psnr": s, "covered_psnr": c, "all_psnr": (s + c) / 2})
    return lines


def test_the_slope_is_read_over_the_end_of_the_curve_in_db_per_minute():
    lines = _curve([10, 14, 15, 15.3], [20, 22, 23, 23.3], minutes_apart=2.0)
    assert gain_per_minute(lines, "scarce_psnr") == pytest.approx(0.3 / 2.0)    # the last 1/3: 4 to 6 min
    assert gain_per_minute(lines[:2], "scarce_psnr") is None                      # one evaluation: no slope
    assert gain_per_minute(lines, "absent") is None


def _saturating(minutes: list[float], tau: float, rise: float = 6.0, start: float = 12.0) -> list[float]:
    """PSNR of a curve whose gain rate decays exponentially: start + rise (1 - exp(-t / tau))."""
    return [start + rise * (1.0 - math.exp(-t / tau)) for t in minutes]


def test_the_decay_of_the_gain_rate_is_read_from_the_curves_middle_and_last_thirds():
    # Evaluations every 30 s up to 11.5 min: the middle third (4-7.5 min) and the last (8-11.5)
    # hold the same layout of points, so their slopes differ by exactly exp(4 min / tau).
    minutes = [0.5 * i for i in range(24)]
    for tau in (2.0, 5.0, 20.0):
        lines = _curve(_saturating(minutes, tau), [26.0] * 24, minutes_apart=0.5)
        assert gain_decay_minutes(lines) == pytest.approx(tau, rel=1e-6)
    # A straight line does not slow down, a curve speeding up neither, and three points are too few.
    assert gain_decay_minutes(_curve([10.0 + i for i in range(12)], [26.0] * 12)) is None
    assert gain_decay_minutes(_curve([10.0 + 0.1 * i * i for i in range(12)], [26.0] * 12)) is None
    assert gain_decay_minutes(_curve([10.0, 12.0, 13.0], [26.0] * 3)) is None
    assert gain_decay_minutes(_curve([20.0] * 12, [26.0] * 12)) is None                  # flat: no rate at all


def test_photo_steps_come_first_until_the_predicted_rate_falls_to_the_break_even():
    assert photo_first_minutes(2.0, 3.0, break_even=0.5) == pytest.approx(3.0 * math.log(4.0))
    assert photo_first_minutes(0.4, 3.0, break_even=0.5) == 0.0            # already below: none
    assert photo_first_minutes(None, 3.0) == 0.0 and photo_first_minutes(float("nan"), 3.0) == 0.0
    assert photo_first_minutes(2.0, None) == math.inf                      # not seen to slow down: all
    assert photo_first_minutes(2.0, 0.0) == math.inf
    # The wait it gives brings the exponential rate exactly to the break-even.
    rate, tau = 1.7, 4.2
    wait = photo_first_minutes(rate, tau)
    assert rate * math.exp(-wait / tau) == pytest.approx(STILL_RISING_DB_PER_MIN)


def test_train_longer_says_how_long_the_bootstrap_takes_photo_steps_first():
    minutes = [0.5 * i for i in range(24)]
    slowing = outlook_from_curve(_curve(_saturating(minutes, 10.0, rise=30.0), [40.0] * 24, minutes_apart=0.5))
    assert slowing.verdict == "train longer" and slowing.photo_first_min is not None
    rate = slowing.scarce_db_per_min
    assert slowing.photo_first_min == pytest.approx(10.0 * math.log(rate / STILL_RISING_DB_PER_MIN), abs=0.01)
    assert f"first {slowing.photo_first_min:.1f} min on photo steps" in slowing.line
    steady = outlook_from_curve(_curve([12.0, 15.0, 17.0, 19.0], [22.0, 25.0, 26.0, 27.0]))
    assert steady.verdict == "train longer" and steady.photo_first_min is None
    assert "spends every step on the photos" in steady.line
    converged = outlook_from_curve(_curve([15.0, 17.0, 17.1, 17.15], [22.0, 24.0, 24.3, 24.5]))
    assert converged.photo_first_min == 0.0
    assert json.loads(json.dumps(steady.to_json()))["photo_first_min"] is None     # JSON-safe


def test_scarce_views_as_good_as_covered_ones_are_nothing_to_repair():
    # statuette's case: the "scarce" group renders as well as the covered one, whatever the curve does
    outlook = outlook_from_curve(_curve([20.0, 23.0, 24.5], [20.5, 23.2, 24.6]))
    assert outlook.verdict == "nothing to repair"
    assert outlook.line.startswith("nothing to repair here: ") and "scarce 24.50 / covered 24.60 dB" in outlook.line
    assert outlook.line.endswith("by default a bootstrap spends every step on the photos")
    assert outlook.gap_db == pytest.approx(0.1)


def test_a_thin_region_still_rising_from_photo_steps_says_train_longer():
    outlook = outlook_from_curve(_curve([12.0, 15.0, 17.0, 19.0], [22.0, 25.0, 26.0, 27.0]))
    assert outlook.verdict == "train longer" and outlook.scarce_db_per_min == pytest.approx(2.0)
    assert "stage I still gains 2.00 dB a minute on the scarce views" in outlook.line


def test_a_thin_converged_region_is_worth_a_repair():
    outlook = outlook_from_curve(_curve([15.0, 17.0, 17.1, 17.15], [22.0, 24.0, 24.3, 24.5]))
    assert outlook.verdict == "repair" and outlook.gap_db == pytest.approx(7.35)
    assert outlook.scarce_db_per_min < STILL_RISING_DB_PER_MIN
    assert "7.3 dB below the covered ones" in outlook.line or "7.4 dB below the covered ones" in outlook.line


def test_without_scarce_and_covered_groups_the_outlook_is_unknown():
    lines = [{"iteration": 0, "train_s": 0.0, "all_psnr": 20.0}, {"iteration": 9, "train_s": 60.0, "all_psnr": 22.0}]
    outlook = outlook_from_curve(lines)
    assert outlook.verdict == "unknown" and "--protocol unstructured" in outlook.line


def test_a_log_without_scores_of_views_the_split_holds_out_does_not_ask_for_another_protocol(tmp_path):
    """A run in blocks (its merged log has no held-out scores; the blocks' curves are theirs) holds
    both groups out: the outlook is unknown because of the log, not the protocol."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.jsonl").write_text(json.dumps({"iteration": 9, "train_s": 60.0, "loss": 0.1}) + "\n")
    split = {"train": [0, 1], "test": [2, 3], "scarce_test": [2], "covered_test": [3]}
    (run / "split.json").write_text(json.dumps(split))
    outlook = run_outlook(run)
    assert outlook.verdict == "unknown" and "probe" in outlook.line and "--protocol" not in outlook.line
    (run / "split.json").write_text(json.dumps({**split, "scarce_test": []}))   # really no scarce group
    assert "--protocol unstructured" in run_outlook(run).line


def test_the_threshold_separates_the_two_cases_at_the_stated_gap():
    at = outlook_from_curve(_curve([20.0, 20.0], [20.0 + NOTHING_TO_REPAIR_DB, 20.0 + NOTHING_TO_REPAIR_DB]))
    below = outlook_from_curve(_curve([20.0, 20.0], [20.0 + 0.99 * NOTHING_TO_REPAIR_DB] * 2))
    assert at.verdict == "repair" and below.verdict == "nothing to repair"


def test_eval_shows_the_outlook_a_bootstrap_recorded_and_a_stage_i_runs_own(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in _curve([15, 17, 17.1], [22, 24, 24.2])))
    when, outlook = recorded_outlook(run)
    assert when == "for a bootstrap" and outlook.verdict == "repair"
    boot = tmp_path / "boot"
    (boot / "bootstrap").mkdir(parents=True)
    (boot / "bootstrap" / "summary.json").write_text(json.dumps({"outlook": outlook.to_json()}))
    assert recorded_outlook(boot) == ("before the bootstrap", outlook)
    (boot / "bootstrap" / "summary.json").write_text(json.dumps({"baseline": True}))    # a baseline records none
    assert recorded_outlook(boot) is None


def test_the_summary_has_one_reader_that_never_follows_a_planted_link(tmp_path):
    from inceptiongs.bootstrap.summary_file import read_summary

    outside = tmp_path / "elsewhere.json"
    outside.write_text(json.dumps({"outlook": {"verdict": "repair", "line": "planted"}}))
    boot = tmp_path / "boot"
    (boot / "bootstrap").mkdir(parents=True)
    (boot / "bootstrap" / "summary.json").symlink_to(outside)
    assert read_summary(boot) is None and recorded_outlook(boot) is None
    (boot / "bootstrap" / "summary.json").unlink()
    (boot / "bootstrap" / "summary.json").write_text("[1, 2]")            # JSON, but not an object
    assert read_summary(boot) is None
    assert read_summary(tmp_path / "absent") is None
