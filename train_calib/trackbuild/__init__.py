"""A track file from what exists (``train-calib build-track``): recorded runs' GNSS and a gradient/limit profile.

``runs``: fixes and speeds of the bags; ``geometry``: the runs' fixes averaged into one polyline and the stops
found in them; ``profile``: TTOBench track JSON or CSV tables, mapped onto the geometry by the stops; ``altitude``:
gradients from the recorded altitude when there is no profile; ``write``: the YAML.
"""
