"""3D drawings of the machines for Rerun (:mod:`tspend.plants.drawing.base`)."""
