"""Sensor calibration: ``sensor.yaml`` measured from APS frames at rest (``measure``) and the
guided pushes that fix mirror and rotation (``guide``)."""
