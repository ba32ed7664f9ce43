"""mspace: feature-based SLAM on the M-space feature representation.

    import mspace
    run = mspace.Run("config/sim_points.yaml", set={"run.seed": 2})   # estimator="<plugin>" swaps it
    summary = run.run()                      # to the end, with the progress bar and outputs
    t, poses = run.evaluated_trajectory()    # NumPy arrays: (N,), (N, 6) x y z θ φ ψ
    for f in run.features(): print(f.type, f.mspace_dim, f.coords, f.covariance)
    saved = mspace.load_map("out/sim_points")

Or step by step: ``while run.step(): ...`` with ``run.pose`` and
``run.robot_covariance`` between steps. Errors in a configuration raise
``mspace.ConfigError`` (a ValueError) with the file, line and key; a bad map
file raises ``mspace.MapFileError``. See docs/python.md.
"""

from ._mspace import (  # noqa: F401  (the compiled part; checks the SDK ABI at import)
    ABI_TAG,
    PLUGIN_DIR,
    ConfigError,
    Feature,
    Map,
    MapFileError,
    Run,
    load_map,
)

__all__ = ["ABI_TAG", "PLUGIN_DIR", "ConfigError", "Feature", "Map", "MapFileError", "Run", "load_map"]
