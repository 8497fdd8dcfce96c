# SPDX-License-Identifier: MIT
"""Zip the add-on for Blender's "Install..." button (Preferences > Add-ons).

    python3 addon/build_zip.py [OUT.zip]      # default: dist/endophoton_addon.zip

The zip holds the folder endophoton_addon/ (with bl_info for Blender 3.4-4.1
and blender_manifest.toml for the 4.2+ extension installer), no caches.
"""

import os
import sys
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
PACKAGE = "endophoton_addon"


def build(out_path):
    out_path = os.path.abspath(out_path)
    os.makedirs(os.path.dirname(out_path), exist_ok=True)
    root = os.path.join(HERE, PACKAGE)
    with zipfile.ZipFile(out_path, "w", zipfile.ZIP_DEFLATED) as zf:
        for folder, dirs, files in os.walk(root):
            dirs[:] = sorted(d for d in dirs if d != "__pycache__")
            for name in sorted(files):
                if name.endswith((".pyc", ".pyo")):
                    continue
                path = os.path.join(folder, name)
                zf.write(path, os.path.relpath(path, HERE))
    return out_path


if __name__ == "__main__":
    default = os.path.join(os.path.dirname(HERE), "dist", f"{PACKAGE}.zip")
    print(build(sys.argv[1] if len(sys.argv) > 1 else default))
