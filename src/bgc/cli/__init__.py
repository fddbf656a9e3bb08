"""The `bgc` command: ``launch`` (the console script's light front door, which replays a warm
run's record before anything heavy loads), ``commands`` (the click commands), ``options``, and
one module per heavy command registered on first use (``accuracy``, ``sweep``)."""
