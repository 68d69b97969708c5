"""``safety-supervisor ui``: the operator's web page, in a process of its own.

A separate rclpy node (``safety_supervisor_ui``) reads the daemon's topics
(:mod:`.node`), keeps the latest picture (:mod:`.hub`) and serves one offline page
with live updates by Server-Sent Events (:mod:`.server`, :mod:`.page`).  Resets go
to the daemon's control socket, never over ROS.  docs/reference/commands.md, ``ui``.
"""
