"""The application shell: the `touch2robot` command, its local Prefect API server, the process
environment of the embedded defaults and the deployment registration. Above flows/, tasks/ and
the library; nothing below imports it except for `app.environment.configure`."""
