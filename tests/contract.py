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


# docs/recording-format.md, "Metadata records": every key of the `run` and `bench` tables.
def recording_metadata_keys(record: str) -> tuple[set[str], set[str]]:
    """The keys docs/recording-format.md documents for the metadata record ``record``
    (``"run"``, ``"bench"``): every key, and those a file has only where its layout needs
    them (the rows that say "absent")."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs/recording-format.md").read_text()
    table = text.split(f"### `{record}`\n", 1)[1].split("\n#", 1)[0]
    keys: set[str] = set()
    layout: set[str] = set()
    for line in table.splitlines():
        if line.startswith("| `"):
            _, first, rest = line.split("|", 2)
            row = set(re.findall(r"`([a-z_]+)`", first))
            keys |= row
            if "absent" in rest:
                layout |= row
    return keys, layout


# Every `bench.adc` table has these (docs/recording-format.md, `bench`).
ADC_KEYS = frozenset(
    {"driver", "sample_rate_hz", "bits", "vref_v", "gain_v_per_dps", "offset_v", "dps_per_count"}
)
