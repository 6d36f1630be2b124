"""The viewer's tests run from a folder of their own (one per test module, so a module's tests
see each other's runs): its jobs, saved PLYs and screenshots go to ./runs in the current folder
(as the command line's), never into the project's checkout."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True, scope="module")
def _runs_in_a_temporary_folder(tmp_path_factory):
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(tmp_path_factory.mktemp("cwd"))
        yield
