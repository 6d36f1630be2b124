"""The training photo the photo views show with the render (images.compose_photo), read from the
scene once per camera: the views redraw it every frame the camera stands near it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from inceptiongs.errors import InputError
from inceptiongs.scene.photo_store import photo_tensor


@dataclass
class TrainingPhotoCache:
    """The last photo read: ``index`` (None: none yet) and its pixels (None: it could not be read)."""

    index: int | None = None
    photo: np.ndarray | None = None

    def photo_of(self, scene, index: int, status) -> np.ndarray | None:
        """The photo of training camera ``index`` of ``scene`` [H, W, 3] in [0, 1], or None when
        there is no scene (a bare model) or the file cannot be read (said in ``status``)."""
        if scene is None:
            return None
        if self.index != index:
            try:
                self.index, self.photo = index, photo_tensor(scene, index).numpy()
            except (InputError, OSError) as exc:
                status.text = f"training photo not shown: {exc}"
                self.index, self.photo = index, None
        return self.photo
