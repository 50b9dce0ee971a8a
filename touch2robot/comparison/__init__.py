"""The method comparison: ``config`` (the profile's ``comparison`` section) and ``statistics``
(cluster-bootstrap intervals over demonstrations, paired differences and tests, Holm, Wilson)."""
