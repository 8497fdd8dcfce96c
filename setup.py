"""setuptools drives CMake to build the native module endophoton._core.

`pip install --no-build-isolation .` (Debian has no PyPI here) configures the
top-level CMakeLists.txt in build/pip, builds only the `_core` target and places
it in the package; the default EEM data ship inside the package.
"""
import os
import shutil
import subprocess
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

ROOT = os.path.dirname(os.path.abspath(__file__))


class CMakeExtension(Extension):
    def __init__(self, name):
        super().__init__(name, sources=[])


class CMakeBuild(build_ext):
    def build_extension(self, ext):
        out_dir = os.path.dirname(os.path.abspath(self.get_ext_fullpath(ext.name)))
        build_dir = os.environ.get("ENDOPHOTON_PIP_BUILD_DIR", os.path.join(ROOT, "build", "pip"))
        os.makedirs(build_dir, exist_ok=True)
        subprocess.check_call([
            "cmake", "-S", ROOT, "-B", build_dir, "-DCMAKE_BUILD_TYPE=Release",
            f"-DPython3_EXECUTABLE={sys.executable}", "-DENDOPHOTON_BUILD_TESTS=OFF",
            f"-DENDOPHOTON_MODULE_OUTPUT_DIR={out_dir}",
        ])
        jobs = str(os.cpu_count() or 2)
        # The module and the .vdb writer library it loads on first use (native/vdb_library.h), side by side.
        subprocess.check_call(["cmake", "--build", build_dir, "--target", "_core", "endophoton_vdb", "-j", jobs])


class BuildPyWithData(build_py):
    def run(self):
        super().run()
        # Default EEMs (endophoton.spectra) and chromophore tables (endophoton.media).
        for folder in ("eem", "media"):
            src = os.path.join(ROOT, "data", folder)
            dst = os.path.join(self.build_lib, "endophoton", "data", folder)
            os.makedirs(dst, exist_ok=True)
            for name in os.listdir(src):
                if name.endswith(".csv"):
                    shutil.copy2(os.path.join(src, name), dst)
        # The SCENE.json schema the loader enforces (endophoton.scene_schema).
        shutil.copy2(os.path.join(ROOT, "docs", "scene.schema.json"),
                     os.path.join(self.build_lib, "endophoton", "data", "scene.schema.json"))


setup(ext_modules=[CMakeExtension("endophoton._core")],
      cmdclass={"build_ext": CMakeBuild, "build_py": BuildPyWithData})
