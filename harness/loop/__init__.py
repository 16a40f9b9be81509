"""The closed loop: the Leaderboard-style agent API (``agent``), one episode at 20 Hz
(``episode``), the reference agent (``route_follower``) and the BEV video of a route
(``render``)."""
