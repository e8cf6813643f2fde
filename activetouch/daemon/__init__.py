"""`activetouch serve`: the process, its device nodes and queryables, the recognition service with
its queue and safety interlock, and the client that talks to it."""
