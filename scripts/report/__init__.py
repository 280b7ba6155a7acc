"""The evidence report (issue 13): `scripts/evidence [--quick] [--out report/]` runs it.

One module per part: api (the handle-group shim), cases (meshes, handle groups, poses), table1,
convergence (time to quality), quality_runs (LARAP beside the surface-ARAP peer), blender_peers and
render_scenes (run inside Blender), gpu (the CUDA entry), plots, summary; __main__ runs them.
"""
