"""Files the project reads and writes that are not scenes: atomic writes, run configurations
as JSON, Gaussian PLY, images, the viewer's flags.json."""
