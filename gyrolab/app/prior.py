"""``--prior DIR_OR_QUERY`` (``compensate``, ``profile design``): the earlier units' model
directories — found under a directory, or the catalogue's latest model of every unit of
a part number (``part-number:PN``) — and the fleet prior learned from them
(:mod:`gyrolab.compensation.prior`)."""

from __future__ import annotations

from gyrolab.app.options import PRIOR_QUERY
from gyrolab.errors import InputError


def prior_dirs(spec: str) -> list[str]:
    """The model directories ``spec`` names (module docstring)."""
    if spec.startswith(PRIOR_QUERY):
        from gyrolab.app.runs import catalogue_models

        return catalogue_models(None, spec[len(PRIOR_QUERY) :], None)
    from gyrolab.compensation.model_dir import ModelDir

    return [str(d) for d in ModelDir.find([spec])]


def load_prior(spec: str):  # -> FleetPrior
    """The fleet prior of ``spec``; too few usable units is one line naming it."""
    from gyrolab.compensation.prior import prior_from_dirs

    try:
        return prior_from_dirs(prior_dirs(spec))
    except ValueError as e:
        raise InputError(spec, str(e)) from None
