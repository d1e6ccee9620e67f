"""Contract values (docs/cli.md, docs/sim-model.md) the tests pin independently of the code."""

# metrics.json: every output (raw, compensated, baselines.<name>) carries these keys.
METRIC_KEYS = frozenset(
    {
        "arw_deg_per_sqrt_h",
        "bias_instability_deg_per_h",
        "bias_stability_deg_per_h",
        "drift_pp_deg_per_s",
        "rms_deg_per_s",
    }
)
