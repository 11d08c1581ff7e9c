"""Experiments on the search: A/B runs of bnb's options on the benchmark's own trials, in
one process, interleaved on one matcher, and the readings of their rows. They are how the
decision records (docs/decisions/) got their numbers; run them from the repository root:

    python -m benchmarks.experiments.options_ab --suites changed --b settle_slack=0.05 --out out/settle
    python -m benchmarks.experiments.options_ab --summarize out/settle/rows.jsonl
    python -m benchmarks.experiments.band_replay out/band/rows.jsonl
    python -m benchmarks.experiments.follow_ab --b band_allowance=0.03 --out out/follow_ab
    python -m benchmarks.experiments.incumbent_ab --poses 8 --scans-per-log 10   # features' proposal seeding bnb

They read the search through its hooks (`BranchAndBoundMatcher.on_peaks`) and set options
on the matcher's `options`; nothing is patched. Their output goes where --out says (out/ is
not committed).
"""
