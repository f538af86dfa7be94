"""The fleet (issue 45, docs/fleet.md): boxes report through an MQTT broker; a service stores
their states in a database; a page, a status table and a service-log export read it.

Modules, one idea each: ``topics`` (the topics and the JSON on them), ``broker`` (the broker
URL, TLS, a paho-mqtt client), ``gateway`` (one box's serial lines to the broker, over
``translator``: the lines as messages, ``publisher``: the connection to the broker, and
``remote_commands``: commands from it), ``collector`` (the broker to the store), ``store``
(SQLite / PostgreSQL), ``web`` (the read-only page), ``export`` (a service log in the run
format), ``localrun`` (a local mosquitto and PostgreSQL for tests and the bench). paho-mqtt and
psycopg come with the [fleet] extra and are imported only where used.
"""
