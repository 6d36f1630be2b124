"""The user's capture as input: COLMAP, transforms.json and LLFF readers (``colmap``,
``transforms``, ``llff``, sharing ``raw``), undistortion, the normalised :class:`loader.Scene`
(``loader.load_scene``) and the procedural demo scene (``demo``)."""
