"""The shape of one servo model's data in :mod:`drivers.dxlsim.model_data`.

:func:`drivers.dxlsim.models.get_model` builds a :class:`~drivers.dxlsim.models.ServoModel`
from it; written down here so the type checker holds every model's entry to it (a key
misspelled or a figure of the wrong kind is an error before anything runs).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, TypedDict

if TYPE_CHECKING:
    from drivers.dxlsim.model_data import Row


class ModelOptions(TypedDict, total=False):
    """What a model's data may give (see :class:`ModelSpec`); a family's shared part
    (``model_data._x330``) is one."""

    #: names of rows it does not have
    drop: tuple[str, ...]
    #: rows it has on top of the table (or in place of one with the same name)
    add: tuple[Row, ...]
    #: name -> the only values accepted (Operating Mode's always come from ``modes``)
    choices: dict[str, tuple[int, ...]]
    #: axes in one case (2 on the 2XL430); default 1
    axes: int
    #: the firmware it reports (addr 6); default ``models.DEFAULT_FIRMWARE``
    firmware: int


class ModelSpec(ModelOptions):
    """One model: its motor figures (as :class:`~drivers.dxlsim.models.ServoModel` names
    them) and how its control table differs from the shared X-series one."""

    model_number: int
    no_load_speed_rpm: float
    nominal_voltage_v: float
    #: None: addr 126 is Present Load (0.1 % of stall), not Present Current
    current_unit_ma: float | None
    stall_torque_nm: float
    stall_current_a: float
    reflected_inertia_kgm2: float
    running_current_a: float
    #: the Operating Modes it accepts
    modes: tuple[int, ...]
    #: name -> (default, lo, hi) where they differ from the shared table
    table: dict[str, tuple[int, int, int]]
