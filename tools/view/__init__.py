"""Pictures and recordings: flight.png (the figure ``flight_png`` on the Pillow engine ``plot_engine``, its scales
``flight_scales``, drawn by the helper process ``flight_picture``), the paper's figure (``plots``), the Rerun layouts
(``views``) and their cache (``layout_cache``), experiment recordings (``recording``), the .rrd files read back
(``rrd_files``), the per-step series files (``series_files``)."""
