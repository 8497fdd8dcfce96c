"""The command line's file checks (``run``, ``render``, ``sweep``): the scene file is read with
every failure named (the file and why), and an output folder (``--out``) is checked before
any work, so that a bad path is exit status 2 naming the option, not an OSError after the run."""
from __future__ import annotations

import contextlib
import os

from .io import read_json_file

__all__ = ["load_scene_file", "check_out_dir", "out_dir_errors"]


def load_scene_file(path: str) -> dict:
    """SCENE.json as parsed JSON; every failure is a ValueError naming the file (endophoton.io's checked
    read: a regular file within its size limit, unique keys, integers Python converts)."""
    return read_json_file(path, "scene file")


def check_out_dir(path: str, option: str = "--out") -> None:
    """Check, before any work, that the output folder ``path`` can be made (the folders it creates
    for the check are removed again); ValueError naming the option and the path, e.g.
    ``--out /proc/x: cannot create the directory: No such file or directory``."""
    made, p = [], os.path.abspath(path)
    while p and not os.path.lexists(p) and os.path.dirname(p) != p:
        made.append(p)
        p = os.path.dirname(p)
    try:
        os.makedirs(path, exist_ok=True)
        if not os.access(path, os.W_OK | os.X_OK):
            raise PermissionError(13, os.strerror(13))
    except (OSError, ValueError) as e:
        raise ValueError(f"{option} {path}: cannot create the directory: {getattr(e, 'strerror', None) or e}") from None
    finally:
        for d in made:  # deepest first
            try:
                os.rmdir(d)
            except OSError:
                pass


@contextlib.contextmanager
def out_dir_errors(path: str, option: str = "--out"):
    """An OSError while the outputs are written is a ValueError naming the option and the path."""
    try:
        yield
    except OSError as e:
        where = f" ({e.filename})" if e.filename else ""
        raise ValueError(f"{option} {path}: cannot write the outputs: {e.strerror or e}{where}") from None
