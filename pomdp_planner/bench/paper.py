"""The paper's published numbers (Lauri et al., Sec. VI), shown next to our measurements.

Only data: the search benchmark (:mod:`.search`) and the experiments' report
(:mod:`.experiments.report`) both read it, so neither imports the other for it.
"""

#: Table II: average % of belief states pruned by depth (S = Z = 8, A = 3, 100 beliefs); shown
#: next to models of that size only.
PAPER_TABLE_II = {2: 26.3, 3: 36.3, 4: 44.9, 5: 52.3, 6: 58.8}

#: Table III: S -> (min, avg, max) % of actions pruned for A = :data:`PAPER_TABLE_III_ACTIONS`
#: (None: not reported).
PAPER_TABLE_III = {
    4: [(75.0, 94.9, 100), (75.0, 83.3, 87.5), (75.0, 78.7, 87.5), (71.9, 74.7, 75.0), (64.1, 72.0, 75.0)],
    8: [(50.0, 75.0, 75), (37.5, 59.5, 62.5), (50.0, 58.0, 75.0), (59.4, 64.9, 71.9), (48.4, 57.6, 67.2)],
    16: [(50.0, 72.7, 75), (50, 65.2, 75.0), (43.8, 61.3, 68.8), (46.9, 55.0, 62.5), (46.9, 55.5, 62.5)],
    32: [(50.0, 73.9, 75), (37.5, 58.5, 62.5), (37.8, 54.9, 62.5), (37.5, 49.9, 59.4), (43.8, 52.6, 59.4)],
    64: [(50.0, 71.9, 75), (37.5, 60.4, 62.5), (43.8, 54.0, 62.5), (37.5, 49.6, 59.4), (40.6, 47.9, 53.1)],
    128: [(50.0, 73.2, 75), (50, 61.1, 62.5), (43.8, 54.7, 56.3), (40.6, 49.3, 53.1), (42.2, 48.3, 53.1)],
    256: [(50.0, 72.8, 75), (50, 60.4, 62.5), (43.8, 50.9, 56.3), (43.8, 49.1, 53.1), None],
}
#: The action counts A of Table III's columns.
PAPER_TABLE_III_ACTIONS = (4, 8, 16, 32, 64)
