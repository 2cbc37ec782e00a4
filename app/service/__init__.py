"""The trial service: every rule about experiments, trials, measurements, users, leases, the
hardware safety gate and the audit log. Routes call one function here; errors are
``app.service.errors.ServiceError`` subclasses."""
