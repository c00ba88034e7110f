"""Writing outputs safely: never over a user's file without --overwrite, never half-written.
The writers are the library's (render/image_files.py, atomic.write_together): the CLI adds its
option's name to the refusal and the check of outputs against the inputs."""

from __future__ import annotations

from pathlib import Path

from ..atomic import refuse_named_twice, same_file
from ..errors import GigapointError
from ..render.image_files import IMAGE_SUFFIXES, check_image_fits, check_output, save_array, save_heights, save_image

__all__ = ["IMAGE_SUFFIXES", "check_image_fits", "check_output", "check_outputs_apart", "save_array", "save_heights", "save_image"]


def check_outputs_apart(outputs, inputs) -> None:
    """One-line errors where an output is an input (a file named, or a point cloud file in a
    folder named: ``--index-out pts.npy --overwrite`` replaced the points it drew) or two outputs
    are one file (the second replaced the first). A glob pattern stands for the files it matches."""
    from ..io import pattern_matches
    from ..io.registry import is_supported_name

    inputs = [m for p in inputs for m in (pattern_matches(p) or [p])]  # ("tiles/*.npy" --index-out tiles/pts.npy)
    given = [Path(o) for o in outputs if o is not None]
    refuse_named_twice(given, GigapointError)
    for out in given:
        if not out.exists():
            continue
        for p in inputs:
            p = Path(p)
            if same_file(out, p) or (p.is_dir() and is_supported_name(out) and same_file(out.parent, p)):
                raise GigapointError(f"{out}: is one of the inputs; write it elsewhere (it would replace the points being read)")
