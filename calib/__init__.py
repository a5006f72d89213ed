"""Calibration: camera intrinsics (ChArUco), laser planes (baseline b, angle alpha per line).

Modules: ``board`` (ChArUco board, detection, printable copy), ``intrinsics`` (camera
fit), ``peaks`` (line rows per column), ``laser`` (b and alpha_k: flat target or board
planes), ``verify`` (range error against z²·σ_u/(f·b)), ``files`` (calibration files,
validated on load), ``captures`` (capture-set manifests), ``simulate`` and ``synthetic``
(capture sets without hardware), ``live`` (a map from a camera backend), ``plots``,
``progress``, and ``commands`` (the ``atris calib`` subcommands). See docs/calibration.md.
"""
