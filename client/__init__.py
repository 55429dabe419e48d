"""Client of the sdcnet service: Python API and the sdc-client command."""
