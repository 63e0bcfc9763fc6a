"""lrr-explorer: the desktop explorer (PySide6 + pyvistaqt + matplotlib) over a Qt-free session model."""
