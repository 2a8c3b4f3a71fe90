"""The ray-traced city: Sionna RT as this package runs it (``ray_tracer``), a city traced (``trace``), its links as a
dataset of the results store (``dataset``) and its 3-D view (``view``)."""
