"""Decision makers that choose actions: scripted oracles now, planned baselines and learned policies later."""
