"""The mission-control view (``cikan view BAG|DIR``, ``cikan mission --view``): a local web page
(plotly.js, served from the ``plotly`` package by the standard library's HTTP server on
127.0.0.1) with the approach in the chief's LVLH frame, tau, every telemetry point against its
limits and a time slider.

- :mod:`cikan_ros.view.data`: what the page shows, as JSON, from a bag, a Monte Carlo directory
  or a bag still being recorded (:mod:`cikan_ros.view.live`);
- :mod:`cikan_ros.view.server`: the HTTP server and the page (``static/``).

No rclpy: a bag is read from its files, a running mission by following what its recorder writes.
"""
