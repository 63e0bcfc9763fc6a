"""The status bar's message: one line, elided to the space it has (the full text in its tooltip), so a
long message (a file path, an out-of-distribution warning) never widens the window; warnings stand out."""
from __future__ import annotations

from PySide6.QtCore import QSize, Qt
from PySide6.QtWidgets import QLabel, QSizePolicy, QWidget

WARNING_STYLE = "color: #a34700; font-weight: bold;"  # amber on the light status bar


class StatusLabel(QLabel):
    def __init__(self, text: str = "", parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
        self._full = ""
        self.is_warning = False
        self.setText(text)

    def setText(self, text: str) -> None:
        """A plain message (a warning shown before is cleared)."""
        self.show_message(text, warning=False)

    def show_message(self, text: str, warning: bool = False) -> None:
        self._full, self.is_warning = text, warning
        self.setStyleSheet(WARNING_STYLE if warning else "")
        self.setToolTip(text)
        self._elide()

    def text(self) -> str:  # the message, not its elided rendering
        return self._full

    def minimumSizeHint(self) -> QSize:
        return QSize(40, super().minimumSizeHint().height())

    def resizeEvent(self, e) -> None:
        super().resizeEvent(e)
        self._elide()

    def _elide(self) -> None:
        line = " ".join(self._full.split())  # one line: a status bar has no room for more
        super().setText(self.fontMetrics().elidedText(line, Qt.TextElideMode.ElideRight, max(self.width() - 4, 20)))
