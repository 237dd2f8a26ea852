"""Finding the `slurry` Python module from inside Blender.

Debian's Blender 3.4 runs Debian's python3.11, so the module built against /usr/bin/python3
loads in it. Blender's sys.path has /usr/local/lib/python3.11/dist-packages, where
`cmake --install BUILD --component python` puts it; elsewhere the add-on's preference
"Slurry Python module folder" names the folder, and otherwise the add-on looks in the
environment variable SLURRY_PYTHON_PATH (folders separated by ':'), beside the `slurry`
executable on the PATH (a build tree's python/ folder, or an install's dist-packages) and in the
usual dist-packages and site-packages folders.
"""
import glob
import importlib
import os
import shutil
import sys


def candidate_folders(preference=""):
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    folders = []
    if preference:
        folders.append(os.path.abspath(os.path.expanduser(preference)))
    folders += [f for f in os.environ.get("SLURRY_PYTHON_PATH", "").split(os.pathsep) if f]
    exe = shutil.which("slurry")
    if exe:
        bindir = os.path.dirname(os.path.realpath(exe))
        folders.append(os.path.join(os.path.dirname(bindir), "python"))  # build/<preset>/bin -> python
        folders.append(os.path.join(os.path.dirname(bindir), "lib", version, "dist-packages"))
    folders += [f"/usr/local/lib/{version}/dist-packages", "/usr/lib/python3/dist-packages",
                os.path.expanduser(f"~/.local/lib/{version}/site-packages")]
    return folders


def has_module(folder):
    return bool(glob.glob(os.path.join(folder, "slurry.cpython-*.so")) or
                glob.glob(os.path.join(folder, "slurry*.so")))


def import_slurry(preference=""):
    """The `slurry` module, or ImportError listing the folders searched."""
    if preference and has_module(preference):
        folder = os.path.abspath(os.path.expanduser(preference))
        if folder not in sys.path:
            sys.path.insert(0, folder)
    try:
        return importlib.import_module("slurry")
    except ImportError:
        pass
    searched = []
    for folder in candidate_folders(preference):
        searched.append(folder)
        if has_module(folder):
            if folder not in sys.path:
                sys.path.insert(0, folder)
            return importlib.import_module("slurry")
    raise ImportError("the slurry Python module was not found; build it (target slurry_python) and set the "
                      "add-on preference 'Slurry Python module folder' to the folder holding "
                      "slurry.cpython-*.so (searched: " + ", ".join(searched) + ")")
