"""Springs and how they are stepped: no I/O, no rig.

``springs``            :class:`Spring` (mass, damping, stiffness, or frequency and damping ratio)
``integrators``        Euler, semi-implicit Euler, Midpoint, RK4; :func:`make_integrator`
``held_step``          the loop's step with the target held over it, as a 3×3 matrix per spring
``stability``          the largest stable step of a method for a spring (:func:`check_stability`)
``stability_algebra``  each method's stability function and growth factor
``simulate``           one spring over time, offline (:func:`simulate`)
"""

from hilsim.dynamics.integrators import INTEGRATORS, Integrator, make_integrator
from hilsim.dynamics.simulate import Trajectory, simulate
from hilsim.dynamics.springs import Spring
from hilsim.dynamics.stability import StabilityReport, check_stability

__all__ = [
    "INTEGRATORS",
    "Integrator",
    "Spring",
    "StabilityReport",
    "Trajectory",
    "check_stability",
    "make_integrator",
    "simulate",
]
