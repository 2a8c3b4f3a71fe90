"""The paper's figures and the book's tables: the registry (``registry``), each figure's data (``data``), their drawing
(``plots``, ``result_plots``, ``city_plots``), tables (``tables``) and the 3-D scenes (``scene3d``)."""
