"""``replay``: a config's monitor run offline over recorded robot data (rosbag2 bags,
MCAP files, JSON-lines traces).

``sources`` reads the recordings into a time-ordered stream of the config's input
values (events or numpy columns); ``cdr`` finds where a primitive field lies in a CDR
payload, so that many messages decode at once. The engine and the command use them.
"""
