"""The channels a discrepancy candidate is scored on (docs/discrepancy.md, "Name"): the
full-rate stream's samples, the temperatures, the gyro's low-frequency output, its noise.

Each module scores the candidates of its channel that a structure lacks (``score``), states
the detection limit of each (``limits``) and gives the fitted simulator parameters of the
ones a fit has (``params``). The gyro channel is generic over the terms every effect
declares beside its physics; the others hold their own effects' tests.
"""
