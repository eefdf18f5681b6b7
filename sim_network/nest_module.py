"""NeuVision's NEST extension module, compiled on first use and cached.

NEST's ``izhikevich`` has no spike-frequency adaptation current and no slow synaptic
current, and the default culture has both. The module (C++ in ``sim_network/nest_cpp/``)
adds one neuron model, ``izhikevich_neuvision``: ``izhikevich`` with the two currents, and
NEST's ``izhikevich`` exactly when both are off (tested). Its neurons can also draw the
culture's noise themselves, the very values sim_network draws, with no current generator
per neuron (7x faster than replaying it).

It is built against the NEST that Python imports: the ``nest-simulator`` wheel ships NEST's
headers and exports its kernel from ``nest/nestkernel_api.so``, so a C++ compiler and the
boost and libltdl headers are all it takes (Debian: ``apt-get install g++ libboost-dev
libltdl-dev``); a NEST built from source is found through its ``nest-config``. One build
(~20 s) per NEST installation and source version, kept under the user's cache directory.
"""

from __future__ import annotations

import fcntl
import functools
import hashlib
import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

#: The neuron model the module registers.
MODEL = "izhikevich_neuvision"
#: The module's name (NEST looks for the symbol ``<name>_LTX_module`` in it).
MODULE_NAME = "neuvisionmodule"
SOURCE_DIR = Path(__file__).resolve().parent / "nest_cpp"
SOURCES = ("izhikevich_neuvision.h", "izhikevich_neuvision.cpp", "neuvisionmodule.cpp")
BUILD_HINT = (
    "it needs a C++20 compiler and the boost and libltdl headers "
    "(Debian/Ubuntu: apt-get install g++ libboost-dev libltdl-dev)"
)


class NestModuleError(RuntimeError):
    """The module could not be built or loaded; the message says why and what to install."""


def cache_dir() -> Path:
    """Where built modules are kept: ``$NEUVISION_CACHE_DIR``, else the user's cache."""
    root = os.environ.get("NEUVISION_CACHE_DIR")
    if root:
        return Path(root)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "neuvision"


def _compiler() -> str:
    """The C++ compiler: ``$CXX``, else g++ or c++ on PATH."""
    named = os.environ.get("CXX")
    cxx = shutil.which(named) if named else shutil.which("g++") or shutil.which("c++")
    if not cxx:
        found = f"$CXX = {named!r} not found" if named else "no C++ compiler found"
        raise NestModuleError(f"{found} to build NeuVision's NEST module: {BUILD_HINT}")
    return cxx


def _uses_cxx11_abi(library: Path) -> bool:
    """Whether NEST's kernel was built with libstdc++'s C++11 ABI: the mangled name of one
    of its functions that takes a std::string says (the wheel's is the old ABI). Read once
    per library version in a process (it is ~25 MB; a run checks the module twice)."""
    stat = library.stat()
    return _abi_of(str(library), stat.st_size, stat.st_mtime_ns)


@functools.lru_cache(maxsize=4)
def _abi_of(library: str, size: int, mtime_ns: int) -> bool:
    with open(library, "rb") as fh:
        return b"StructuralPlasticityNode21get_synaptic_elementsENSt7__cxx11" in fh.read()


def nest_package_dir() -> Path:
    """The directory of the ``nest`` package Python would import (without importing it)."""
    spec = importlib.util.find_spec("nest")
    if spec is None or spec.origin is None:
        raise NestModuleError("NEST is not installed, so its module cannot be built")
    return Path(spec.origin).resolve().parent


def build_flags(pkg: Path) -> list[str]:
    """The compiler's flags for the NEST in ``pkg``: includes, ABI, kernel library.

    Parameters
    ----------
    pkg : Path
        The ``nest`` package's directory (`nest_package_dir`).

    Returns
    -------
    list of str

    Raises
    ------
    NestModuleError
        Neither the wheel's layout nor a working ``nest-config`` was found.
    """
    kernel = pkg / "nestkernel_api.so"
    include = pkg / "include"
    if kernel.is_file() and (include / "nest" / "nest_extension_interface.h").is_file():
        abi = int(_uses_cxx11_abi(kernel))
        return [
            f"-D_GLIBCXX_USE_CXX11_ABI={abi}",
            f"-I{include / 'nest'}",
            f"-I{include}",
            str(kernel),  # linked by its absolute path: the very library Python has loaded
        ]
    config = shutil.which("nest-config")
    if config is None:
        raise NestModuleError(
            f"NEST at {pkg} ships no headers and no nest-config is on PATH: cannot build "
            "NeuVision's NEST module against it"
        )
    try:
        cflags = subprocess.run([config, "--cflags"], capture_output=True, text=True, check=True)
        libs = subprocess.run([config, "--libs"], capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError) as exc:
        raise NestModuleError(f"{config} failed: {exc}") from exc
    return cflags.stdout.split() + libs.stdout.split()


def module_path(pkg: Path | None = None) -> Path:
    """The module built for this NEST, building it first if it is not in the cache.

    Parameters
    ----------
    pkg : Path, optional
        The ``nest`` package's directory; default: the one Python would import. NEST itself
        is not imported here.

    Returns
    -------
    Path
        The shared library (`install` loads it into NEST).

    Raises
    ------
    NestModuleError
        No compiler, or the build failed (the compiler's last lines in the message).
    """
    pkg = nest_package_dir() if pkg is None else Path(pkg)
    cxx = _compiler()
    flags = build_flags(pkg)
    key = hashlib.sha256()
    for name in SOURCES:
        key.update((SOURCE_DIR / name).read_bytes())
    key.update(" ".join([cxx, *flags]).encode())
    for lib in pkg.glob("*.so"):  # a NEST reinstalled in the same place builds anew
        key.update(f"{lib.name} {lib.stat().st_size} {lib.stat().st_mtime_ns}".encode())
    out_dir = cache_dir() / f"nest-{key.hexdigest()[:16]}"
    target = out_dir / f"{MODULE_NAME}.so"
    if target.is_file():
        return target
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".lock", "w") as lock:  # one build when several processes start
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not target.is_file():
            _compile(cxx, flags, target)
    return target


def _compile(cxx: str, flags: list[str], target: Path) -> None:
    sources = [str(SOURCE_DIR / name) for name in SOURCES if name.endswith(".cpp")]
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=target.parent)
    os.close(fd)
    cmd = [cxx, "-std=c++20", "-O2", "-fPIC", "-shared", "-o", tmp, *sources, *flags]
    print(f"building NeuVision's NEST module into {target.parent} (once, ~20 s)", file=sys.stderr)
    try:
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            tail = "\n".join(done.stderr.strip().splitlines()[-12:])
            raise NestModuleError(
                f"building NeuVision's NEST module failed ({BUILD_HINT}):\n{tail}"
            )
        os.chmod(tmp, 0o755)
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def install(nest, path: Path) -> None:
    """Load the module into NEST's kernel (again after every ``nest.ResetKernel``).

    Parameters
    ----------
    nest : module
        The imported ``nest`` package (on the thread that imported it).
    path : Path
        From `module_path`.
    """
    try:
        nest.Install(str(path))  # with its .so: ltdl takes any dot in the path for a suffix
    except Exception as exc:  # NEST's DynamicModuleManagementError
        raise NestModuleError(f"NEST could not load {path}: {exc}") from exc
