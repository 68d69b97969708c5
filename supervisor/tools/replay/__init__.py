"""``replay``: recorded robot data (rosbag2 bags, MCAP files, JSON-lines traces) read
back as a time-ordered stream of the config's input values, for a monitor run offline.

``sources`` opens the recordings and yields the events; ``cdr`` finds where a field of
a fixed-size message lies, so that many messages decode at once.
"""
