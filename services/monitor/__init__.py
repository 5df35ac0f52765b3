"""The run's progress line, summary and run folder (``service``), and the plots it draws
(``plot``)."""

from services.monitor.plot import line_plot

__all__ = ["line_plot"]
