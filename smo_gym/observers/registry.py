r"""The registry of observer families: each family is declared once, next to its class, and read everywhere.

A family is registered by decorating its class::

    @register_observer("alpha-beta", steps=(alpha_beta_rows,), bound=2, calibrate=..., examples=(dict(...),))
    class AlphaBeta(Observer): ...

and the registry then provides, with nothing else to edit:

* the name for :func:`smo_gym.observers.make_observer`, the wrapper, the command line and
  :func:`smo_gym.differentiate` (:data:`OBSERVERS`, or :data:`MODEL_BASED_OBSERVERS`);
* its parameters (names and defaults, from the constructor) for :mod:`smo_gym.specs`;
* what its gains need from calibration (:meth:`Family.bound_order`, :meth:`Family.needs_calibration`) and its
  gain rule (:attr:`Family.calibrate`), read by :func:`smo_gym.calibration.default_observer`;
* the compiled code of every step it declares (:func:`smo_gym.observers._kernels.register_step`): the batch
  kernel, its shared-parameter variant, the offline drivers and the wrapper's fused driver, all cached on disk (a
  step whose own cached helpers call functions of ``_kernels.py``, a channel step, registers itself with
  ``register_step(rows, helpers=...)``: numba checks a cached function's own file only);
* the parameter sets on which the contract tests run (batching, masked reset, non-finite input, pickling,
  ``run`` equals a loop of ``update``), one per discretization at least.

Every module of :mod:`smo_gym.observers` is imported with the package, so a family in a new module of the
package is found without an import elsewhere.

A gain rule receives a :class:`smo_gym.calibration.Calibration` (per channel: worst-case bounds and typical levels
of the derivatives, the noise level and the quantization step) and the derivative order :meth:`Family.bound_order`
returns; sliding-mode gains read the worst case (:meth:`~smo_gym.calibration.Calibration.bound`), linear and
Kalman gains the typical level (:meth:`~smo_gym.calibration.Calibration.rms`).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from .._validation import check_int_in_range
from . import _kernels

__all__ = [
    "FAMILIES",
    "MODEL_BASED_OBSERVERS",
    "OBSERVERS",
    "Family",
    "family_of",
    "lipschitz_rule",
    "lipschitz_unit_rule",
    "register_observer",
]

#: family name -> :class:`Family`, in the order of registration
FAMILIES: dict[str, Family] = {}
#: name -> class of the model-free families (built by name alone), for the wrapper, the CLI and ``differentiate``
OBSERVERS: dict[str, type] = {}
#: name -> class of the families that take the control input (built with a dynamics object or a fitted input model,
#: updated with ``update(y, u)``)
MODEL_BASED_OBSERVERS: dict[str, type] = {}


def lipschitz_rule(cls, calibration, order: int, kwargs: dict):
    """The sliding-mode gain rule: ``lipschitz`` = the worst-case bound of ``order``, per channel (Levant 2003)."""
    return cls(dt=calibration.dt, **kwargs, lipschitz=calibration.bound(order))


def lipschitz_unit_rule(cls, calibration, order: int, kwargs: dict):
    """:func:`lipschitz_rule` for a family with a ``unit`` parameter (the weights of its terms of positive degree
    have a dimension in the signal's unit): the calibration's :attr:`~smo_gym.calibration.Calibration.unit` per
    channel, unless given."""
    return lipschitz_rule(cls, calibration, order, {"unit": calibration.unit, **kwargs})


@dataclass(frozen=True)
class Family:
    """One observer family as registered (:func:`register_observer`).

    Attributes
    ----------
    name : str
        The short name (``"super-twisting"``, ``"levant"``, ...).
    cls : type
        Its :class:`~smo_gym.observers.Observer` subclass.
    steps : tuple of :class:`smo_gym.observers._kernels.Step`
        The compiled steps its discretizations run (the class's ``_kernel`` is one of their kernels); empty for a
        family written in NumPy.
    bound : int or None
        The order of the derivative its gains bound (2: acceleration); ``None``: ``order + 1``.
    calibrate : callable or None
        The gain rule ``calibrate(cls, calibration, order, kwargs) -> observer``: a
        :class:`smo_gym.calibration.Calibration` and the order :meth:`bound_order` returns (module notes);
        ``None``: nothing to calibrate.
    given : tuple of tuple of str
        Sets of constructor arguments any of which, given together, set every gain (no calibration then).
    examples : tuple of dict
        Constructor arguments (without ``dt``) for the contract tests, covering every discretization.
    model_based : bool
        Built with a dynamics object or a fitted input model and updated with ``update(y, u)``: not built by name,
        no offline or fused drivers.
    order_from : callable or None
        ``order_from(kwargs) -> int``: the number of derivatives estimated, from the constructor arguments (given
        ones over the defaults), for a family whose constructor does not call it ``order``; ``None``: the
        ``order`` argument, else its default.
    """

    name: str
    cls: type
    steps: tuple = ()
    bound: int | None = None
    calibrate: Callable | None = None
    given: tuple[tuple[str, ...], ...] = ()
    examples: tuple[dict, ...] = field(default_factory=tuple)
    model_based: bool = False
    order_from: Callable | None = None

    @property
    def parameters(self) -> dict[str, Any]:
        """Parameter name -> default (``inspect.Parameter.empty`` if required) of the constructor (without ``dt``)."""
        return {
            p.name: p.default
            for p in inspect.signature(self.cls).parameters.values()
            if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD) and p.name not in ("self", "dt")
        }

    @property
    def compiled(self) -> bool:
        """Whether the family runs compiled steps only (then it has offline and fused drivers)."""
        return bool(self.steps) and not self.model_based

    def order(self, kwargs: dict | None = None) -> int:
        """The number of derivatives estimated with these constructor arguments (``order``, else its default, or
        what :attr:`order_from` says)."""
        if kwargs is not None and not isinstance(kwargs, dict):
            raise TypeError(f"expected observer options as a dict, actual value: {kwargs!r:.80}")
        if self.order_from is not None:
            defaults = {k: v for k, v in self.parameters.items() if v is not inspect.Parameter.empty}
            order = self.order_from({**defaults, **(kwargs or {})})
        else:
            default = self.parameters.get("order", 1)
            order = (kwargs or {}).get("order", 1 if default is inspect.Parameter.empty else default)
        # the constructor checks the order's range; here only that it is one (its type, before int() of it)
        return check_int_in_range("order", order, 0, 2**31)

    def bound_order(self, kwargs: dict | None = None) -> int:
        """The order of the derivative the gains bound: :attr:`bound`, or ``order + 1``."""
        return self.order(kwargs) + 1 if self.bound is None else self.bound

    def needs_calibration(self, kwargs: dict | None = None) -> bool:
        """Whether :attr:`calibrate` has a gain to fill with these constructor arguments."""
        kw = kwargs or {}
        return self.calibrate is not None and not any(all(k in kw for k in keys) for keys in self.given)


def register_observer(
    name: str,
    *,
    steps=(),
    bound: int | None = None,
    calibrate: Callable | None = None,
    given=(),
    examples=(),
    model_based: bool = False,
    order_from: Callable | None = None,
):
    """Class decorator: register an observer family under ``name`` (module notes; arguments as :class:`Family`,
    ``steps`` given as the ``rows`` functions of :func:`smo_gym.observers._kernels.register_step`).

    Sets the class's ``name``. Raises ``ValueError`` for a name registered by another class.
    """

    def decorate(cls):
        if name in FAMILIES and FAMILIES[name].cls is not cls:
            raise ValueError(f"expected a new observer name, actual value: {name!r} is {FAMILIES[name].cls.__name__}")
        cls.name = name
        family = Family(
            name=name,
            cls=cls,
            steps=tuple(_kernels.register_step(rows) for rows in steps),
            bound=bound,
            calibrate=calibrate,
            given=tuple(tuple(keys) for keys in given),
            examples=tuple(dict(e) for e in examples),
            model_based=model_based,
            order_from=order_from,
        )
        FAMILIES[name] = family
        (MODEL_BASED_OBSERVERS if model_based else OBSERVERS)[name] = cls
        return cls

    return decorate


def family_of(observer) -> Family | None:
    """The family an observer object belongs to: the one registered with exactly its class (a subclass of a
    registered class is a family of its own, unregistered: ``None``)."""
    for family in FAMILIES.values():
        if type(observer) is family.cls:
            return family
    return None
