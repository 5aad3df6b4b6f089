"""The pictures of the documentation: the environment's ``render()`` (:mod:`.render`) and the
scenario tree's plan (:mod:`.tree`)."""
