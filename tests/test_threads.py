import os

import pytest

from inceptiongs.threads import torch_thread_count


@pytest.mark.parametrize("setting, expected", [("1", 1), ("3", 3), (" 1 ", 1)])
def test_a_users_thread_setting_wins(monkeypatch, setting, expected):
    monkeypatch.setenv("OMP_NUM_THREADS", setting)
    assert torch_thread_count() == expected


@pytest.mark.parametrize("setting", ["", "0", "-2", "two", "1.5"])
def test_no_or_bad_setting_takes_at_most_two_cores(monkeypatch, setting):
    monkeypatch.setenv("OMP_NUM_THREADS", setting)
    assert torch_thread_count() == min(2, os.cpu_count() or 1)
