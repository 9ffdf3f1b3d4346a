"""The endpoint groups: ``detect`` (POST /detect, /detect/batch), ``stream`` (WebSocket /stream),
``health`` (/healthz, /readyz, /metrics, /model)."""
