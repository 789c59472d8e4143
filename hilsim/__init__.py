"""hilsim: animatronic joints as damped springs, integrated in real time and streamed to servos.

The numerical core::

    import hilsim
    spring = hilsim.Spring(m=1.0, c=0.5, k=15.0)            # or Spring.from_animation(2.0, 0.3)
    traj = hilsim.simulate(spring, x0=1.0, h=0.01, t_end=10.0, method="rk4")
    traj.t, traj.x, traj.v                                   # numpy arrays
    print(hilsim.check_stability(spring, h=0.001, method="rk4"))

Importing ``hilsim`` never imports matplotlib or dynamixel_sdk.
"""

from hilsim.dynamics.integrators import INTEGRATORS, Integrator, make_integrator
from hilsim.dynamics.simulate import Trajectory, simulate
from hilsim.dynamics.springs import Spring
from hilsim.dynamics.stability import StabilityReport, check_stability

__version__ = "0.1.0"

__all__ = [
    "INTEGRATORS",
    "Integrator",
    "Spring",
    "StabilityReport",
    "Trajectory",
    "__version__",
    "check_stability",
    "make_integrator",
    "simulate",
]
