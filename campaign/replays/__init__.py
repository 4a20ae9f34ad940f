"""Replays: the takeoff and landing cases flown on the reference and on each identified model, open
and closed loop; their Part 60 metrics, plots and uncertainty bands."""
