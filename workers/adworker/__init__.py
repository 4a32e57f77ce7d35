"""activedesign simulation worker: leases jobs, simulates, trains, evaluates, reports."""
