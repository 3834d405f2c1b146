"""The companion service: config, camera capture, MAVLink link, fusion, health, lifecycle."""
