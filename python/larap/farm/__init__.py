"""Chunked, deterministic animation bakes on a render farm (engine-neutral; see docs/farm.md).

A bake of frames F0..F1 is split into chunks (:mod:`plan`); each chunk runs headless Blender
(:mod:`blender_chunk`, command lines from :mod:`command`) and writes one PC2 point cache per object
plus a manifest (:mod:`manifest`), each under a temporary name renamed when complete. The merge
(:mod:`merge`) checks every chunk (size, checksum, settings) and every frame, then writes one PC2 per
object that Blender's Mesh Cache modifier plays back without LARAP. :mod:`runner` runs the chunks
on any executor (a Dask cluster: :mod:`dask_runner`), reporting and re-running failed chunks.

    python3 -m larap.farm plan --frames 1-100 --chunk-size 25 --preroll 3
    python3 -m larap.farm dask shot.blend --object Body --frames 1-100 --chunk-size 25 --out bake/
"""
from .plan import Chunk, BakeJob, parse_frames, plan_chunks
from .pc2 import PC2Error, read_pc2, read_pc2_header, write_pc2
from .merge import MergeError, merge_bake

__all__ = ["Chunk", "BakeJob", "parse_frames", "plan_chunks", "PC2Error", "read_pc2", "read_pc2_header",
           "write_pc2", "MergeError", "merge_bake"]
