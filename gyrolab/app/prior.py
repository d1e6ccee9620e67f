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
    """The fleet prior of the units ``spec`` names (a model whose causal model is a
    network, or that has none, is skipped and named in the prior's ``skipped``); fewer
    than two usable units is one line naming ``spec``."""
    from gyrolab.compensation.model_dir import ModelDir
    from gyrolab.compensation.prior import UnitEntry, learn_prior, structured_of

    dirs = prior_dirs(spec)
    units, skipped = [], {}
    for d in dirs:
        got = structured_of(ModelDir(d).load().causal)
        if got is None:
            skipped[d] = "its causal model is not a structured one"
        else:
            units.append(UnitEntry(d, *got))
    if len(units) < 2:
        raise InputError(
            spec,
            f"a fleet prior needs at least 2 units with a structured causal model; "
            f"{len(units)} of {len(dirs)} model directories have one",
        )
    return learn_prior(units, skipped)
