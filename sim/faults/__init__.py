"""Fault injection, fuzzing and the long-run memory check of the service (`sdvl faults`)."""
