"""setupcam: camera-based workpiece setup for CNC machine tools."""

__version__ = "0.1.0"
