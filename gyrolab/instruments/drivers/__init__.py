"""One module per instrument driver; each registers a
:class:`~gyrolab.instruments.registry.DriverSpec` when imported (the registry imports them
all). docs/instruments.md, "Adding a driver", says how to add one."""
