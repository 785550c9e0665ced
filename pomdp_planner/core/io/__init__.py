"""Model file formats: YAML (ours) and Cassandra .POMDP."""
