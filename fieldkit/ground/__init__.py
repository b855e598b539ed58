"""The operator's ground station: watch the swarm live and command it over the radio.

`core` is the station itself, sans-I/O (frames and time in, the swarm view and frames out);
`web` serves its page on localhost; `station` runs it on a radio, beside a simulated swarm,
and bridges a simulated radio to UDP (the gateway). See docs/ground.md.
"""
