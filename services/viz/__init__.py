"""The Foxglove live view: message conversion (``convert``, needs the ``viz`` extra) and the
WebSocket server (``service``)."""

__all__: list[str] = []
