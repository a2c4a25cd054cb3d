"""What a robot reads from a finished map: a dense occupancy volume over a bounded region, 2D navigation grids and
semantic costmaps in the ROS map_server format, and a Euclidean signed distance field with its incremental update."""
