"""Reproducing the paper: Table 1, the learning curves, the pictures, and a demo for newcomers.

- :mod:`apr.reproduce.runs`: reading run folders (config.json, metrics.csv, eval/*.json).
- :mod:`apr.reproduce.table`: Table 1 from run folders (``build_table1``, ``render_table1``).
- :mod:`apr.reproduce.campaign`: ``apr reproduce table1``: presets x seeds, resumable, then the table.
- :mod:`apr.reproduce.plot`: ``apr plot``: held-out success against grasps (Figure 4).
- :mod:`apr.reproduce.policies`: a policy to picture: a run's checkpoint, a packaged one, or an untrained one.
- :mod:`apr.reproduce.episodes`: in-process episodes that keep what the pictures need.
- :mod:`apr.reproduce.figures`: ``apr figures``: Figures 1 G/H, 3, 5, 6 and a GIF of evaluation episodes.
- :mod:`apr.reproduce.demo`: ``apr demo``: a policy on held-out objects, with a short report.
"""
