"""Turning a lab's continuous logs (ROS 1 ``.bag``, ROS 2 bag directories) into PIMBS
recordings: ``mapping`` (which topics and fields), ``bagread`` (time series from the log),
``held`` (the held poses in them), ``convert`` (the format-1 recording)."""
