"""What surveyors make of a point cloud, beyond a picture: cross-sections (section.py), change
between two surveys (change.py), stockpile volumes (volume.py), ground classes by SMRF
(ground.py), noise classes (noise.py) and heights above ground (heights.py) over a shared raster
and point passes (ground_raster.py), orthophotos and surface models as GeoTIFFs (orthophoto.py).
Their rasters' cells (which cell a point is in, where its centre lies) follow raster_grid.py's rules.

Each reads its clouds through io/lod (files, folders, octrees; the read filters), draws through
render where it needs a picture, and writes through io/render's writers; the CLI's commands
(section, change, volume, classify, render --gsd) and gigapoint's top-level calls (gp.section,
gp.change, gp.volume, gp.classify_ground, gp.orthophoto, ...) are thin layers over them. The
package imports nothing at start-up: each module is loaded by the call that needs it.
"""
