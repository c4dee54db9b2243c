"""RiemannianFlow: stable skills on Riemannian manifolds learned with ImitationFlow. Never imports MuJoCo."""
