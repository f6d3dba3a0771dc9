"""``ivfm rehearse``: the readiness profile and the static checks (``readiness``, the
shipped profile in ``profiles/``), and the rehearsal that flies the profile's flights
and says go or no-go (``rehearse``). May import ``ground.check`` and everything below."""
