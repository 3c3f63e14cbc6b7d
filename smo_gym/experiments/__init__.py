"""Experiments: the analysis tools on top of the library, behind ``smo-gym compare`` and ``smo-gym control``.

The layer above :mod:`smo_gym.wrappers` and :mod:`smo_gym.control`: nothing in the library imports it. Its modules
run rollouts and simulations, and print tables and draw plots (matplotlib, the ``plots`` extra, is imported
only when a plot is drawn):

:mod:`smo_gym.experiments.compare`
    velocity observers side by side on the same measurements of one MuJoCo rollout (``smo-gym compare``);
:mod:`smo_gym.experiments.control`
    the output-feedback control experiments on linear plant models and the MuJoCo Furuta pendulum
    (``smo-gym control``, ``scripts/control_experiments.py``).
"""

__all__: list[str] = []
