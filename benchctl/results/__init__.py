"""A run's results for a production line: measurements with limits, a decision rule and
outcomes (``measurements``) and the run's JSON record with its schema (``record``)."""
