"""The LeRobot import swap: customer code keeps ``from lerobot... import FeetechMotorsBus``.

``armnet-runtime`` calls :func:`install_lerobot_remote_mode` before it loads the
customer's script. It imports nothing: it asks to be called back when the job itself
imports a module that defines one of LeRobot's hardware classes
(:mod:`armnet_runtime.lerobot.import_hook`), so a job that never imports LeRobot starts
like plain Python, and one that does pays only LeRobot's own import. Right after such a
module's code has run, and before anything else can bind a name from it, the class is
replaced by its remote proxy; the package that re-exports it then binds the proxy, and
so does every module imported afterwards (``lerobot.robots.so_follower.so_follower``
binds ``FeetechMotorsBus`` when it is imported). Modules loaded before the call (an
in-process caller that imported LeRobot first) are patched where they bound the class.
Data types (``Motor``, ``MotorCalibration``, ``OpenCVCameraConfig``, enums) stay real:
they cross the socket as tagged JSON.
"""

from __future__ import annotations

import abc
import importlib.util
import logging
import os
import sys
from types import ModuleType

from armnet_runtime import env
from armnet_runtime.lerobot import import_hook
from armnet_runtime.lerobot.remote_arx5 import RemoteARX5Arm
from armnet_runtime.lerobot.remote_camera import RemoteOpenCVCamera
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus
from armnet_runtime.lerobot.remote_object import RemoteObjectProxy

logger = logging.getLogger("armnet_runtime.lerobot")

SWAP_TARGETS: tuple[tuple[str, tuple[str, ...], type[RemoteObjectProxy]], ...] = (
    ("FeetechMotorsBus", ("lerobot.motors.feetech.feetech", "lerobot.motors.feetech"), RemoteFeetechMotorsBus),
    ("OpenCVCamera", ("lerobot.cameras.opencv.camera_opencv", "lerobot.cameras.opencv"), RemoteOpenCVCamera),
    ("ARX5Arm", ("arx5_common",), RemoteARX5Arm),
)
"""(class name, modules that define or re-export it in LeRobot 0.4.x, its proxy)."""

_originals: dict[int, tuple[type, type[RemoteObjectProxy]]] = {}
"""id(original class) -> (original class, proxy); kept so a second call still finds them."""


def _record_original(module: ModuleType, name: str, proxy: type[RemoteObjectProxy]) -> bool:
    """Remember ``module.name`` as an original hardware class; False when it is not one."""
    found = getattr(module, name, None)
    if isinstance(found, type) and not issubclass(found, RemoteObjectProxy):
        _originals[id(found)] = (found, proxy)
        register_virtual_bases(found, proxy)
        return True
    return False


def _swap_when_imported(module: ModuleType) -> None:
    """The import hook's callback: swap the classes a just-imported module defines."""
    patched: list[str] = []
    for name, modules, proxy in SWAP_TARGETS:
        if module.__name__ in modules and _record_original(module, name, proxy):
            setattr(module, name, proxy)
            patched.append(f"{module.__name__}.{name}")
    if patched:
        logger.info("armnet LeRobot remote mode: patched %s", ", ".join(patched))


def register_virtual_bases(original: type, proxy: type[RemoteObjectProxy]) -> list[str]:
    """Make ``isinstance(proxy_obj, Base)`` hold for every abstract base of ``original``.

    LeRobot's bases are ABCs (``Camera``; ``MotorsBusBase`` and ``SerialMotorsBus`` in
    0.4.x, ``MotorsBus`` before), so the proxy is registered as their virtual
    subclass: code that checks ``isinstance(bus, SerialMotorsBus)`` accepts it,
    while the proxy inherits none of their hardware code. Returns the bases' names.
    """
    registered: list[str] = []
    for base in original.__mro__[1:]:
        if isinstance(base, abc.ABCMeta) and base is not object and not issubclass(proxy, base):
            base.register(proxy)
            registered.append(base.__qualname__)
    return registered


def _candidate_modules() -> list[tuple[str, ModuleType]]:
    roots = {modules[0].split(".")[0] for _, modules, _ in SWAP_TARGETS}
    return sorted(
        (name, module)
        for name, module in list(sys.modules.items())
        if isinstance(module, ModuleType) and name.split(".")[0] in roots
    )


def _patch_loaded_modules() -> list[str]:
    patched: list[str] = []
    for module_name, module in _candidate_modules():
        namespace = getattr(module, "__dict__", None)
        if not isinstance(namespace, dict):
            continue
        for attr, value in list(namespace.items()):
            entry = _originals.get(id(value))
            if entry is not None and entry[0] is value:
                setattr(module, attr, entry[1])
                patched.append(f"{module_name}.{attr}")
    return patched


def install_lerobot_remote_mode() -> None:
    """Replace LeRobot's bus, camera and arm classes with the connector proxies.

    Skipped (one log line) when ``ARMNET_LOCAL_CONTAINER`` is set: the container
    then drives the hardware directly. A no-op when LeRobot is not installed.
    Imports nothing: a module not yet imported is swapped when the job imports it
    (one info line per module, naming the ``module.name`` bindings replaced); modules
    already imported are patched now (one info line listing them). Idempotent.
    """
    if os.environ.get(env.LOCAL_CONTAINER):
        logger.info(
            "armnet LeRobot remote mode skipped: %s is set, LeRobot drives the hardware directly",
            env.LOCAL_CONTAINER,
        )
        return
    if importlib.util.find_spec("lerobot") is None:
        logger.debug("armnet LeRobot remote mode: LeRobot is not installed, nothing to patch")
        return
    loaded = [(name, module_name, proxy) for name, modules, proxy in SWAP_TARGETS
              for module_name in modules if module_name in sys.modules]
    for name, module_name, proxy in loaded:
        _record_original(sys.modules[module_name], name, proxy)
    patched = _patch_loaded_modules()
    if patched:
        logger.info("armnet LeRobot remote mode installed: patched %s", ", ".join(patched))
    elif loaded:
        logger.info("armnet LeRobot remote mode already installed: nothing new to patch")
    awaited = sorted({module_name for _, modules, _ in SWAP_TARGETS for module_name in modules
                      if module_name not in sys.modules} - set(import_hook.watched()))
    for module_name in awaited:
        import_hook.when_imported(module_name, _swap_when_imported)
    if awaited:
        logger.debug("armnet LeRobot remote mode: will swap on import of %s", ", ".join(awaited))
