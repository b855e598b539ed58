"""Over-the-air script updates: keys, signed patches, the version store, spreading, rollback.

A script version is a `Release` (its .bo, .bdb and .bpos bytes), named by the SHA-256 of its
bytecode. The operator signs and encrypts a patch from the version the swarm runs to the new
one; robots pass it on to each other, verify it, agree on the switch and roll back together
if the new version fails (docs/update.md).
"""
