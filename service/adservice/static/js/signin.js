// Sign-in: the form that exchanges a token for the session cookie, who is signed in, and
// sign-out (api.js holds the session; the page never keeps the token).

import { currentSession, signIn, signOut } from './api.js';

export const ASK = 'This server requires a token. Sign in with a reader token or higher:';

export function askToSignIn(text) {
  const auth = document.querySelector('[data-auth]');
  auth.hidden = false;
  auth.querySelector('[data-auth-text]').textContent = text;
  document.querySelector('[data-signed-in]').hidden = true;
}

function showSignedIn(session) {
  document.querySelector('[data-auth]').hidden = true;
  const who = document.querySelector('[data-signed-in]');
  who.hidden = !session.auth || !session.signed_in;
  who.querySelector('[data-who]').textContent = session.name
    ? `${session.name} (${session.role})`
    : session.role ?? '';
}

/** Ask for a token if the server wants one and none is signed in; else say who is. */
export async function checkSession() {
  const session = await currentSession();
  if (session.auth && !session.signed_in) askToSignIn(ASK);
  else showSignedIn(session);
}

/** Wire the form and the sign-out button: `signedIn` runs after a sign-in is accepted,
 * `signedOut` after the session ended. */
export function bindSignIn({ signedIn, signedOut }) {
  document.querySelector('[data-auth] form').addEventListener('submit', async (event) => {
    event.preventDefault();
    const field = event.target.elements.token;
    try {
      showSignedIn(await signIn(field.value));
      field.value = '';
      signedIn();
    } catch (error) {
      field.value = '';
      askToSignIn(`The server refused that token (${error.message}). Try another:`);
    }
  });
  document.querySelector('[data-sign-out]').addEventListener('click', async () => {
    await signOut();
    signedOut();
    askToSignIn('Signed out. Sign in with a reader token or higher:');
  });
}
