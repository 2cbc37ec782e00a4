"""Workers: separate processes that claim trials from the server over HTTP and run them.

`sim` runs rollouts on all cores; `hardware` runs confirmed trials on a robot through a driver
(`drivers`), behind its own safety gate (`gate`).
"""
