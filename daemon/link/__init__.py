"""The MAVLink link to the autopilot, in three parts.

- **The wire contract** (pure): :mod:`.conditions` (the daemon's conditions, an enum with
  their texts: docs/wire.md's table is written from it), :mod:`.contract` (condition ->
  DISTANCE_SENSOR fields, time_boot_ms and its ordering), :mod:`.vocabulary` (MAVLink
  enum values, the cm rules), :mod:`.settings` (what the autopilot's parameters must be
  for the range on the wire).
- **The transport with its peers and signing**: :mod:`.endpoint` (:class:`MavlinkLink`,
  what the daemon holds), :mod:`.pump` (its I/O thread), :mod:`.queue`, :mod:`.inbound`,
  :mod:`.peers` (the one udpin owner, the TCP read gate), :mod:`.signing`,
  :mod:`.transport` / :mod:`.streams` / :mod:`.urls` (the byte pipes), :mod:`.messages`
  (what is sent), :mod:`.settings_check` (the autopilot's settings read back),
  :mod:`.lines` (rate-limited log lines).
- **The clock with its deadlines**: :mod:`.clock` (:class:`SendClock`).

Import the module you need (``from uav_depth.daemon.link.endpoint import MavlinkLink``):
this package imports nothing itself, so the config loader can use :mod:`.vocabulary`
without the link.
"""
