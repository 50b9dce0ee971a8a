"""The contact feedback view's library: a demonstration and its robot trajectories read from the lake
(``demonstration``), the LEAP Hand scene posed by MuJoCo's kinematics (``pose``), a recording followed while
it is written (``follow``), the user-study protocol and its ratings file (``study``) and the Rerun export
(``export``). The browser app itself is ``app/view.py``."""
