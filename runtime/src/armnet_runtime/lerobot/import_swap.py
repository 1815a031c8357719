"""The LeRobot import swap: customer code keeps ``from lerobot... import FeetechMotorsBus``.

``armnet-runtime`` calls :func:`install_lerobot_remote_mode` before it loads the
customer's script. It replaces LeRobot's hardware classes with the remote proxies
everywhere a module holds them: the defining module, the package that re-exports
it, and every ``lerobot.*`` module already imported that bound the class at import
time (``lerobot.robots.so_follower.so_follower`` binds ``FeetechMotorsBus`` when it
is imported). Modules imported afterwards bind the proxies from the patched
packages. Data types (``Motor``, ``MotorCalibration``, ``OpenCVCameraConfig``,
enums) stay real: they cross the socket as tagged JSON.
"""

from __future__ import annotations

import abc
import importlib
import importlib.util
import logging
import os
import sys
from types import ModuleType

from armnet_runtime import env
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


def _find_originals() -> None:
    for name, modules, proxy in SWAP_TARGETS:
        for module_name in modules:
            try:
                if importlib.util.find_spec(module_name.split(".")[0]) is None:
                    continue
                module = importlib.import_module(module_name)
            except Exception as exc:  # noqa: BLE001 - a broken optional dependency must not break the job
                logger.debug("armnet LeRobot remote mode: cannot import %s: %r", module_name, exc)
                continue
            found = getattr(module, name, None)
            if isinstance(found, type) and not issubclass(found, RemoteObjectProxy):
                _originals[id(found)] = (found, proxy)
                register_virtual_bases(found, proxy)


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
    Idempotent; the single info line lists exactly the ``module.name`` bindings
    it replaced.
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
    _find_originals()
    patched = _patch_loaded_modules()
    if patched:
        logger.info("armnet LeRobot remote mode installed: patched %s", ", ".join(patched))
    elif _originals:
        logger.info("armnet LeRobot remote mode already installed: nothing new to patch")
    else:
        checked = [module for _, modules, _ in SWAP_TARGETS for module in modules]
        logger.warning(
            "armnet LeRobot remote mode: LeRobot is installed but none of its hardware classes were found "
            "(checked %s); remote robot access may fail. Supported: lerobot 0.4.x",
            ", ".join(checked),
        )
