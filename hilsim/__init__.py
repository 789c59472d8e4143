"""hilsim: animatronic joints as damped springs, integrated in real time and streamed to servos.

Run a show::

    import hilsim

    with hilsim.Show("configs/demo.toml", virtual_time=True, duration=2.0) as show:
        result = show.run()          # blocks; show.stop() from another thread ends it safely
    print(result.exit_code, result.run_dir, result.summary["ticks"])

The numerical core::

    spring = hilsim.Spring(m=1.0, c=0.5, k=15.0)            # or Spring.from_animation(2.0, 0.3)
    traj = hilsim.simulate(spring, x0=1.0, h=0.01, t_end=10.0, method="rk4")
    traj.t, traj.x, traj.v                                   # numpy arrays
    print(hilsim.check_stability(spring, h=0.001, method="rk4"))

Importing ``hilsim`` never imports matplotlib or dynamixel_sdk; the show's names load on
first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hilsim.dynamics import (
    INTEGRATORS,
    Integrator,
    StabilityReport,
    Trajectory,
    check_stability,
    make_integrator,
    simulate,
)
from hilsim.dynamics.springs import Spring
from hilsim.exit_codes import ExitCode

if TYPE_CHECKING:
    from hilsim.rig import Rig, RigError, load_rig
    from hilsim.show import Show, ShowError, ShowRefusedError, ShowResult

#: names loaded on first use (the show and rig modules import the drivers)
_LAZY = {
    "Rig": "hilsim.rig",
    "RigError": "hilsim.rig",
    "load_rig": "hilsim.rig",
    "Show": "hilsim.show",
    "ShowError": "hilsim.show",
    "ShowRefusedError": "hilsim.show",
    "ShowResult": "hilsim.show",
}

__all__ = [
    "INTEGRATORS",
    "ExitCode",
    "Integrator",
    "Rig",
    "RigError",
    "Show",
    "ShowError",
    "ShowRefusedError",
    "ShowResult",
    "Spring",
    "StabilityReport",
    "Trajectory",
    "__version__",
    "check_stability",
    "load_rig",
    "make_integrator",
    "simulate",
]


def _version() -> str:
    """The installed distribution's version (importlib.metadata costs a command's start-up
    some 25 ms, so it is read only when asked for: ``hilsim --version``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("hilsim")
    except PackageNotFoundError:  # a source tree that was never installed
        return "0+unknown"


def __getattr__(name: str) -> Any:
    if name == "__version__":
        value: Any = _version()
        globals()[name] = value
        return value
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'hilsim' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
