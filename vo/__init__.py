"""The SDVL tracker: pure computation, no I/O, no asyncio."""
