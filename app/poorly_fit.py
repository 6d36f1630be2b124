"""The open run's training photos it fits poorly (RUN/view_fit.json, train/view_fit.py): their
frustums are drawn apart and the Training panel steps the camera through them, worst first."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from inceptiongs.errors import InputError
from inceptiongs.train.view_fit import read_poorly_fit


@dataclass
class PoorlyFitPhotos:
    """``psnr``: image name -> PSNR in dB, worst first; ``shown``: which of them
    :meth:`next_photo` went to last (-1: none yet)."""

    psnr: dict[str, float] = dataclasses.field(default_factory=dict)
    shown: int = -1

    def next_photo(self, view, status) -> None:
        """Stand ``view`` (view.View) at the next poorly fit photo's camera (worst first, then
        around) and say which in ``status``; nothing when none of them is among its cameras."""
        indices = {camera.name: i for i, camera in enumerate(view.cameras)}
        names = [name for name in self.psnr if name in indices]
        if not names:
            return
        self.shown = (self.shown + 1) % len(names)
        name = names[self.shown]
        view.snap_to_camera(indices[name])
        status.text = (f"{name}: training photo {self.shown + 1} of {len(names)} the model fits "
                       f"poorly ({self.psnr[name]:.1f} dB)")


def read_poorly_fit_photos(run_dir: Path | None, status) -> PoorlyFitPhotos:
    """The poorly fit photos of ``run_dir``: none without a run or a report; a report that cannot
    be read is said in ``status`` (the viewer goes on without it)."""
    if run_dir is None:
        return PoorlyFitPhotos()
    try:
        return PoorlyFitPhotos(read_poorly_fit(run_dir))
    except InputError as exc:
        status.text = f"photo fit report not read: {exc}"
        return PoorlyFitPhotos()
