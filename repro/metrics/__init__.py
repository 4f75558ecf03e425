"""Metrics of the three papers: pure functions on arrays/tensors (see docs/metrics.md).

Import from the modules (several functions share their module's name, so nothing is
re-exported here): :mod:`.fid` (FID, FID_train/FID_test), :mod:`.accuracy` (top-k, confusion,
MultiAct label merging from :mod:`.label_merge`), :mod:`.diversity` (Diversity,
Multimodality), :mod:`.apd` (APD, n-APD), :mod:`.modes` (GMM/silhouette modes,
mode-homogeneity), :mod:`.trajectory` (Δ_Traj, Δ_JPE, dist_e), :mod:`.transitions` (Δ_pose,
Δ_vel), :mod:`.qualification` (Action/Motion QR).
"""
