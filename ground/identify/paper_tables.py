"""The paper's published numbers (docs/reproducing.md), printed beside ours.

Their metric ("MSE") is not defined in the paper, so only orderings and margins compare.
"""

from __future__ import annotations

# Table 2: validation RMSE of the identified models, (T1FM, IVFM).
TABLE_2_VALIDATION_RMSE = {"phi": (1.5958, 1.4016), "theta": (1.1717, 1.1009),
                           "psi": (0.2072, 0.1930)}

# Tables 3-5: "MSE" per axis, (IVFC, T1FC).
TABLE_3_ATTITUDE_HOLD = {"theta": (22.5090, 23.0242), "phi": (44.9816, 81.8549),
                         "psi": (1.0554, 1.0587)}
TABLE_4_INERTIA = {
    "attitude-jr-10": {"theta": (7.492, 13.216), "phi": (17.548, 49.829)},
    "attitude-jr-15": {"theta": (7.590, 9.693), "phi": (17.310, 32.508)},
    "attitude-jr-20": {"theta": (8.060, 9.118), "phi": (17.295, 31.033)},
}
TABLE_5_POSITION_KICK = {"x": (39.7494, 46.6442), "y": (123.8104, 127.3148),
                         "z": (30.7955, 30.7955)}

PAPER_MSE_BY_SCENARIO = {"attitude-hold": TABLE_3_ATTITUDE_HOLD, **TABLE_4_INERTIA,
                         "position-kick": TABLE_5_POSITION_KICK}
