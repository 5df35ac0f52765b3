"""Shepherd's code, one sub-package per kind:

- ``services.core``: shared maths (transforms, the camera model, projection), the mounts, the
  world and obstacle model, and the compiled-kernel plumbing; no bus inside.
- ``services.runtime``: the bus over Zenoh, deployment files, the launcher, service context.
- ``services.<service>``: one sub-package per service (``sim``, ``frame_source``,
  ``vertex_extractor``, ``pose_estimator``, ``mission_controller``, ``camera_planner``,
  ``ir_transmitter``, ``calibration``, ``monitor``, ``viz``): pure algorithm modules and a
  thin ``service.py`` on the bus.
- ``services.tools``: the ``shepherd`` command and its operator tools (echo, record/replay,
  bench, experiments, soak).
- ``services.data``: files shipped with the package (the default deployment, the paper's
  camera).
"""
